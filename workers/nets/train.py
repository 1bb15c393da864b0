"""Training of MVNet and HandSegNet within a time budget, resumable, on the GPU when there is one.

Both loops: Adam, a cosine learning-rate decay over the budget (time-based, so a budget fits any
machine; or over `max_steps` when that ends training first; held open until `min_steps` where a floor is
given), a partial checkpoint every `checkpoint_every_s` (weights, optimiser, step, seconds) that `resume=True`
continues from, and a final checkpoint with metadata (checkpoints.py).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as nnf

from workers.geometry.projection import stack_cameras
from workers.nets.checkpoints import (
    CheckpointError,
    NetKind,
    build_metadata,
    check_compatible,
    checkpoint_path,
    read_checkpoint,
    save_checkpoint,
)
from workers.nets.configs import HandSegNetConfig, MVNetConfig, NetsConfig
from workers.nets.data import HandSegDataset, MVNetDataset, augment_mvnet_batch, sample_handseg_batch
from workers.nets.handsegnet import HandSegNet
from workers.nets.losses import (
    gaussian_targets,
    heatmap_2d_loss,
    scorevolume_loss,
    softargmax_loss,
    world_to_grid,
)
from workers.nets.mvnet import MVNet
from workers.nets.unproject import project_batched

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainProgress:
    """Reported after every step: step count, training seconds so far, smoothed loss, and the share of training
    done (`schedule_fraction`: 1 ends it)."""

    step: int
    seconds: float
    loss: float
    fraction: float = 0.0


# A step floor holds training open past its seconds budget, but never past this many budgets (a loaded machine).
MIN_STEPS_MAX_BUDGETS = 2.5  # cpu-small's 1650 steps take ~180 s of a 90 s budget on an AVX2 CPU


def schedule_fraction(seconds: float, step: int, budget_s: float, min_steps: int | None = None,
                      max_steps: int | None = None) -> float:
    """How far training is (training ends at 1; the learning rate decays over it): the seconds budget, held open
    until `min_steps` steps (at most MIN_STEPS_MAX_BUDGETS budgets), or `max_steps` steps if that comes first.

    A step floor makes a machine without native bfloat16 (AVX2) learn what one with it learns in the same budget,
    at the cost of time: the steps, not the seconds, are what the network learns from."""
    by_time = seconds / budget_s
    if min_steps:
        by_time = max(min(by_time, step / min_steps), seconds / (MIN_STEPS_MAX_BUDGETS * budget_s))
    if max_steps is None:
        return by_time
    return max(by_time, step / max_steps if max_steps > 0 else 1.0)


@dataclass(frozen=True)
class TrainResult:
    """model: trained (eval mode); checkpoint: the final .pt; metadata: what it records."""

    model: torch.nn.Module
    checkpoint: Path
    metadata: dict[str, Any]


def default_device() -> torch.device:
    """CUDA when available, else CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def _resolve(config: NetsConfig | MVNetConfig | HandSegNetConfig, kind: NetKind
             ) -> tuple[MVNetConfig | HandSegNetConfig, str]:
    if isinstance(config, NetsConfig):
        return (config.mvnet if kind == "mvnet" else config.handsegnet), config.name
    return config, "custom"


def _cosine_lr(base: float, fraction: float) -> float:
    return base * max(0.02, 0.5 * (1 + math.cos(math.pi * min(1.0, fraction))))


def _train_loop(kind: NetKind, model: torch.nn.Module, config: MVNetConfig | HandSegNetConfig, config_name: str,
                step_fn: Callable[[np.random.Generator, float], torch.Tensor], sample_ids: tuple[str, ...],
                budget_s: float, checkpoint_dir: Path | str, resume: bool,
                progress: Callable[[TrainProgress], None] | None, seed: int, max_steps: int | None,
                checkpoint_every_s: float, extra: dict[str, Any] | None, warm_start: dict[str, Any] | None = None,
                min_steps: int | None = None) -> TrainResult:
    if budget_s <= 0:
        raise ValueError(f"budget_s must be positive, got {budget_s}")
    if min_steps is not None and (isinstance(min_steps, bool) or not isinstance(min_steps, int) or min_steps < 1):
        raise ValueError(f"min_steps must be a positive integer or None, got {min_steps!r}")
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    step, spent_before = 0, 0.0
    partial = checkpoint_path(checkpoint_dir, kind, partial=True)
    if warm_start is not None:
        extra = {**(extra or {}), "init_from": warm_start}
    if resume and partial.is_file():
        state = read_checkpoint(partial)
        check_compatible(state["metadata"], kind, config, partial)
        if state["metadata"].get("seed") != seed:
            log.warning("%s: resuming a run of seed %s with seed %s", partial, state["metadata"].get("seed"), seed)
        model.load_state_dict(state["model"])
        if "optimizer" not in state:
            raise CheckpointError(f"{partial}: no optimiser state to resume from")
        optimizer.load_state_dict(state["optimizer"])
        step, spent_before = int(state["metadata"]["steps"]), float(state["metadata"]["train_seconds"])
        if "init_from" in state["metadata"]:  # the interrupted run's warm start, whatever this call asked for
            extra = {**(extra or {}), "init_from": state["metadata"]["init_from"]}
        log.info("resuming %s from %s: step %d, %.0f s trained", kind, partial, step, spent_before)
    torch.manual_seed(seed + step)
    rng = np.random.default_rng([seed, step])
    model.train()
    started = time.perf_counter()
    last_save = started
    smoothed = float("nan")

    def meta(seconds: float) -> dict[str, Any]:
        return build_metadata(kind, config, config_name=config_name, seed=seed, sample_ids=sample_ids, steps=step,
                              train_seconds=seconds, metrics={"train_loss": smoothed}, extra=extra)

    while True:
        spent = spent_before + time.perf_counter() - started
        fraction = schedule_fraction(spent, step, budget_s, min_steps, max_steps)
        if fraction >= 1:
            break
        for group in optimizer.param_groups:
            group["lr"] = _cosine_lr(config.lr, fraction)
        loss = step_fn(rng, fraction)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        step += 1
        value = float(loss.detach())
        smoothed = value if math.isnan(smoothed) else 0.95 * smoothed + 0.05 * value
        if progress:
            now = spent_before + time.perf_counter() - started
            progress(TrainProgress(step, now, smoothed, min(1.0, schedule_fraction(now, step, budget_s, min_steps,
                                                                                   max_steps))))
        if time.perf_counter() - last_save > checkpoint_every_s:
            save_checkpoint(partial, model, meta(spent_before + time.perf_counter() - started), optimizer)
            last_save = time.perf_counter()
    seconds = spent_before + time.perf_counter() - started
    save_checkpoint(partial, model, meta(seconds), optimizer)
    metadata = meta(seconds)
    final = save_checkpoint(checkpoint_path(checkpoint_dir, kind), model, metadata)
    log.info("%s trained: %d steps in %.0f s, loss %.4f -> %s", kind, step, seconds, smoothed, final)
    return TrainResult(model.eval(), final, metadata)


def warm_start_weights(model: torch.nn.Module, kind: NetKind, config: MVNetConfig | HandSegNetConfig,
                       init_from: Path | str) -> dict[str, Any]:
    """Load the weights of a final checkpoint of the same architecture (an earlier round's network) into
    `model`; returns what the new checkpoint's metadata records about it ("init_from").

    Raises:
        CheckpointError: missing, unreadable, of another kind or another architecture.
    """
    path = Path(init_from)
    state = read_checkpoint(path)
    check_compatible(state["metadata"], kind, config, path)
    try:
        model.load_state_dict(state["model"])
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: weights do not fit the configuration ({exc})") from None
    meta = state["metadata"]
    previous = meta.get("init_from") or {}
    return {"path": str(path), "steps": int(meta.get("steps", 0)),
            "train_seconds": float(meta.get("train_seconds", 0.0)),
            "num_training_samples": int(meta.get("num_training_samples", 0)),
            "round_index": meta.get("round_index"),
            # total optimisation behind these weights, over every earlier warm-started round
            "cumulative_steps": int(meta.get("steps", 0)) + int(previous.get("cumulative_steps", 0)),
            "cumulative_train_seconds": round(float(meta.get("train_seconds", 0.0))
                                              + float(previous.get("cumulative_train_seconds", 0.0)), 3)}


def mvnet_loss(model: MVNet, batch: dict[str, np.ndarray], cams: dict[str, torch.Tensor],
               device: torch.device, only_2d: bool = False) -> torch.Tensor:
    """The configured loss of one batch from `augment_mvnet_batch` (unlabelled = NaN keypoints ignored):
    score-volume (or soft-argmax) loss, plus the auxiliary 2D keypoint loss when configured; `only_2d`:
    the auxiliary loss alone (the 2D warm-up, no unprojection or 3D network)."""
    cfg = model.config
    if only_2d and cfg.aux_2d_weight <= 0:
        raise ValueError("only_2d needs the 2D keypoint head (aux_2d_weight > 0)")
    centers = torch.as_tensor(batch["centers_world"], device=device)
    K_crop = torch.as_tensor(batch["K_crop"], device=device)
    view_valid = torch.as_tensor(batch["view_valid"], device=device)
    rotation = torch.as_tensor(batch["grid_rotation"], device=device) if "grid_rotation" in batch else None
    dist, R, t = cams["dist"], cams["R"], cams["t"]
    if "view_index" in batch and batch["view_index"].shape[1] != R.shape[0]:  # a subset of the views per frame
        index = torch.as_tensor(batch["view_index"], device=device)
        dist, R, t = dist[index], R[index], t[index]
    crops = torch.as_tensor(batch["crops"], device=device)
    keypoints = torch.as_tensor(batch["keypoints_3d"], device=device)
    weights = torch.isfinite(keypoints).all(-1).float()
    keypoints = torch.nan_to_num(keypoints)
    detector = {}
    if cfg.heatmap_source == "detector":
        if "detector_px" not in batch:
            raise ValueError("a detector-backed MVNet trains on a dataset with detections (build_mvnet_dataset "
                             "with heatmap_source='detector')")
        detector = {"detector_px": torch.as_tensor(batch["detector_px"], device=device),
                    "detector_scores": torch.as_tensor(batch["detector_scores"], device=device)}
    if only_2d:
        features, loss = model.encode_views(crops), torch.zeros((), device=device)
    else:
        scores, features = model(crops, K_crop, dist, R, t, centers, view_valid, return_features=True,
                                 grid_rotation=rotation, **detector)
        grid = world_to_grid(keypoints, centers, cfg.grid_size, cfg.grid_side_m, rotation)
        if cfg.loss == "softargmax":
            loss = softargmax_loss(scores, grid, weights)
        else:
            loss = scorevolume_loss(scores, gaussian_targets(grid, cfg.grid_size, cfg.sigma_voxels), weights)
    if cfg.aux_2d_weight > 0:
        pixels, depth = project_batched(keypoints, K_crop, dist, R, t)  # (B, C, K, 2) crop pixels
        h = features.shape[-1]
        pixels_map = (pixels + 0.5) * (h / cfg.crop_px) - 0.5  # crop pixels -> feature-map pixels
        inside = ((pixels_map > -0.5) & (pixels_map < h - 0.5)).all(-1) & (depth > 1e-3)
        w2d = weights[:, None, :] * view_valid[:, :, None].float() * inside.float()
        loss = loss + cfg.aux_2d_weight * heatmap_2d_loss(model.heatmaps_2d(features), pixels_map, w2d,
                                                          cfg.aux_2d_sigma_px)
    return loss


def train_mvnet(dataset: MVNetDataset, config: NetsConfig | MVNetConfig, budget_s: float,
                checkpoint_dir: Path | str, *, resume: bool = True,
                progress: Callable[[TrainProgress], None] | None = None, seed: int = 0, max_steps: int | None = None,
                device: torch.device | str | None = None, checkpoint_every_s: float = 60.0,
                extra_metadata: dict[str, Any] | None = None, init_from: Path | str | None = None,
                min_steps: int | None = None) -> TrainResult:
    """Train MVNet on `dataset` for `budget_s` seconds of training (cumulative over resumes).

    Args:
        dataset: crops and 3D labels (data.build_mvnet_dataset); its crop size must match the config.
        config: a named configuration (its .mvnet is used) or an MVNetConfig.
        budget_s: training seconds; max_steps: optional step limit as well; min_steps: optional step floor that
            holds training open past the budget (`schedule_fraction`).
        checkpoint_dir: the round's folder (checkpoints.round_dir); gets mvnet.pt, mvnet.json, mvnet.partial.pt.
        resume: continue from mvnet.partial.pt when present (same architecture required).
        progress: called after every step with TrainProgress.
        seed: seeds the initialisation, batches and augmentation.
        device: default CUDA when available, else CPU.
        init_from: a final mvnet.pt of the same architecture (an earlier round's) to start from instead of a
            random initialisation (warm start: training accumulates over rounds); recorded in the metadata as
            "init_from". The 2D-only warm-up is skipped then (the 3D network already has features to work
            on). A partial checkpoint to resume from takes precedence.
    Returns:
        TrainResult with the model in eval mode.
    Raises:
        CheckpointError: init_from is missing or of another architecture.
    """
    cfg, name = _resolve(config, "mvnet")
    if dataset.crop_px != cfg.crop_px or not math.isclose(dataset.crop_radius_m, cfg.crop_radius_m):
        raise ValueError(f"dataset crops ({dataset.crop_px} px, {dataset.crop_radius_m} m) do not match the "
                         f"configuration ({cfg.crop_px} px, {cfg.crop_radius_m} m)")
    if len(dataset) == 0:
        raise ValueError("empty training set")
    if cfg.heatmap_source == "detector" and dataset.detector_px is None:
        raise ValueError("the configuration is detector-backed (heatmap_source='detector') but the dataset has no "
                         "detections; build it with that configuration (build_mvnet_dataset)")
    device = torch.device(device) if device is not None else default_device()
    torch.manual_seed(seed)
    model = MVNet(cfg)
    warm = warm_start_weights(model, "mvnet", cfg, init_from) if init_from is not None else None
    if cfg.detector_offsets:  # this round's, learned from its labels (a warm start's are the previous round's)
        model.set_keypoint_offsets(dataset.detector_offsets)
    model = model.to(device)
    cams = stack_cameras(list(dataset.cameras), device=device)
    batch_size = min(cfg.batch_frames, len(dataset))
    warmup = 0.0 if warm is not None else cfg.warmup_2d_fraction

    def step(rng: np.random.Generator, fraction: float) -> torch.Tensor:
        indices = rng.choice(len(dataset), size=batch_size, replace=False)
        return mvnet_loss(model, augment_mvnet_batch(dataset, indices, cfg, rng), cams, device,
                          only_2d=fraction < warmup)

    return _train_loop("mvnet", model, cfg, name, step, dataset.sample_ids, budget_s, checkpoint_dir, resume,
                       progress, seed, max_steps, checkpoint_every_s, extra_metadata, warm, min_steps)


def handseg_loss(logits: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy plus (1 - soft IoU) over the batch; logits, targets (B, H, W)."""
    bce = nnf.binary_cross_entropy_with_logits(logits, targets)
    prob = torch.sigmoid(logits)
    inter = (prob * targets).sum()
    union = (prob + targets - prob * targets).sum().clamp(min=1.0)
    return bce + (1 - inter / union)


def train_handsegnet(dataset: HandSegDataset, config: NetsConfig | HandSegNetConfig, budget_s: float,
                     checkpoint_dir: Path | str, *, resume: bool = True,
                     progress: Callable[[TrainProgress], None] | None = None, seed: int = 0,
                     max_steps: int | None = None, device: torch.device | str | None = None,
                     checkpoint_every_s: float = 60.0, extra_metadata: dict[str, Any] | None = None,
                     init_from: Path | str | None = None, min_steps: int | None = None) -> TrainResult:
    """Train HandSegNet on random patches of `dataset` for `budget_s` training seconds.

    Arguments as `train_mvnet` (init_from: a final handsegnet.pt of the same architecture); files
    handsegnet.pt / .json / .partial.pt in `checkpoint_dir`.
    """
    cfg, name = _resolve(config, "handsegnet")
    if len(dataset) == 0:
        raise ValueError("empty training set")
    device = torch.device(device) if device is not None else default_device()
    torch.manual_seed(seed)
    model = HandSegNet(cfg)
    warm = warm_start_weights(model, "handsegnet", cfg, init_from) if init_from is not None else None
    model = model.to(device)

    def step(rng: np.random.Generator, fraction: float) -> torch.Tensor:
        images, targets = sample_handseg_batch(dataset, cfg, rng)
        logits = model(torch.as_tensor(np.ascontiguousarray(images), device=device))
        return handseg_loss(logits, torch.as_tensor(np.ascontiguousarray(targets), device=device))

    return _train_loop("handsegnet", model, cfg, name, step, dataset.sample_ids, budget_s, checkpoint_dir, resume,
                       progress, seed, max_steps, checkpoint_every_s, extra_metadata, warm, min_steps)
