"""`handloop bench mvnet-precision`: where the detector-backed MVNet gains or loses precision against the lift it
starts from (issue 15), on green-screen frames, with step budgets (not time budgets: the figures do not depend on
the shared machine's load).

A synthetic capture (default 640 px, 8 sequences x 12 frames, a seed no test uses) gives its green-screen training
sequences; the last two of them (other subjects) are held out whole, and every 4th frame of the others is held out
too ("same sequences": the loop's case, where MVNet predicts the unlabelled frames of the sequences it was trained
on). Every frame is detected once (chroma-key masks, cached beside the capture). Measured against ground truth,
per keypoint, on each held-out set: (a) the detector's lifted keypoints (`lift`), moved by the keypoint offsets
learned from the training frames (`lift_corrected`) and by those and the pose term (`lift_pose_corrected`), (b) each
configuration's untrained MVNet (its readout of the detector's unprojected maps: the U-Net's head starts at zero),
(c) the same MVNet after N
training steps on the remaining frames (each step count trained from scratch, the cosine schedule over N).
Keys per set: median / mean / p90 keypoint error (mm), the fraction of keypoints within 10 mm, and the median
over frames of the largest keypoint error (the heuristic's "max 3D distance" compares per keypoint at 10 mm), and
the mean confidence (eq. 8).

`heuristic`: for the largest step count, each held-out frame is fitted from the MVNet's prediction as a round fits
it (workers/tasks/inputs.from_prediction: its 3D keypoints weighted by their confidences, the later rounds' loss
weights) with two kinds of masks, and the paper's heuristic (services/review/verification.heuristic_verdict, paper
thresholds) judges the fit against the prediction: `gt_hand_masks`, the ground-truth hand masks (what a perfect
HandSegNet would give: the IoU criterion as the paper presumes it), and `chroma_key`, the capture's chroma-key
foreground cut at MVNet's predicted wrist, the loop's reference (`heuristic_iou_reference=chroma_key`, the same
function: workers.fitting.reference_masks.prediction_reference_masks). Reported: frames
accepted, their precision (true mean vertex error <= 10 mm), the failed criteria, medians of the criteria's
quantities and of the fits' true vertex error.
"""

from __future__ import annotations

import os
import re
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.stats import spearmanr

from backend.bench.common import emit
from backend.services.review.verification import HeuristicThresholds, heuristic_verdict
from backend.settings import get_settings
from workers.capture.reader import load_frame_masks, load_ground_truth, read_capture
from workers.capture.schema import FrameRef
from workers.fitting.config import FitConfig, LossWeights
from workers.fitting.engine import FittingEngine
from workers.fitting.inputs import FrameObservations
from workers.fitting.reference_masks import prediction_reference_masks
from workers.geometry.camera import Camera
from workers.handmodel.loading import load_hand_model
from workers.nets.configs import CONFIGS, MVNetConfig, NetsConfig, get_config
from workers.nets.data import MVNetDataset, build_mvnet_dataset
from workers.nets.detections import DetectionCache, detect_frames, learn_detector_offsets
from workers.nets.keypoint_maps import image_to_crop_px
from workers.nets.mvnet import MVNet
from workers.nets.predict import predict_from_crops
from workers.nets.train import train_mvnet
from workers.synth.generator import generate_capture
from workers.synth.plan import SynthConfig

DEFAULT_CONFIGS = ("cpu-small-detector",)
DEFAULT_STEPS = (100, 300)
HELD_OUT_EVERY = 4  # every 4th frame of the training subjects' sequences is held out


def keypoint_stats(errors_mm: np.ndarray) -> dict[str, float | int]:
    """(M, K) keypoint errors (NaN = not predicted) -> summary figures, mm."""
    finite = errors_mm[np.isfinite(errors_mm)]
    if finite.size == 0:
        return {"median_mm": float("nan"), "mean_mm": float("nan"), "p90_mm": float("nan"), "within_10mm": 0.0,
                "frame_max_median_mm": float("nan"), "keypoints": 0}
    return {"median_mm": round(float(np.median(finite)), 2), "mean_mm": round(float(np.mean(finite)), 2),
            "p90_mm": round(float(np.percentile(finite, 90)), 2),
            "within_10mm": round(float((finite <= 10).mean()), 3),
            "frame_max_median_mm": round(float(np.nanmedian(np.nanmax(errors_mm, axis=1))), 1),
            "keypoints": int(finite.size)}


def ensure_capture(data_dir: Path, width: int, sequences: int, frames: int, seed: int) -> Path:
    """The synthetic capture, written once and reused when its folder holds a readable capture."""
    root = data_dir / f"precision-w{width}-s{sequences}-f{frames}-seed{seed}"
    if (root / "capture.json").is_file():
        try:
            read_capture(root)
            return root
        except Exception as exc:  # any unreadable capture is re-created
            sys.stderr.write(f"re-creating the capture {root}: {exc}\n")
    generate_capture(root, SynthConfig(num_sequences=sequences, frames_per_sequence=frames, seed=seed,
                                       width_px=width), force=True)
    return root


def predict(model: MVNet, data: MVNetDataset) -> Any:
    """`model`'s KeypointPrediction on the dataset's crops (grid at the lifted keypoints' centroid) and detections
    (corrected by the learned keypoint offsets where the configuration has them)."""
    K = np.stack([np.asarray(c.K, np.float64) for c in data.cameras])
    return predict_from_crops(model, data.crops, data.K_crop, data.centers_world, data.cameras, data.view_valid, 4,
                              image_to_crop_px(data.detector_px, data.K_crop, K), data.detector_scores,
                              data.detector_world)


def mvnet_stats(model: MVNet, data: MVNetDataset) -> dict[str, Any]:
    """keypoint_stats of `model`'s errors on the dataset, with its mean confidence (eq. 8)."""
    pred = predict(model, data)
    errors = 1000 * np.linalg.norm(pred.keypoints_3d - data.keypoints_3d, axis=-1)
    return {**keypoint_stats(errors), "mean_confidence": round(float(pred.sample_confidence.mean()), 3),
            **confidence_ranking(np.asarray(pred.confidence, np.float64), errors)}


def confidence_ranking(confidence: np.ndarray, errors_mm: np.ndarray) -> dict[str, float | int | None]:
    """Whether eq. 8's confidence ranks predictions by their error. confidence, errors_mm: (M, K).

    Keys: Spearman correlation of keypoint confidence vs keypoint error (`spearman_keypoint`) and of a frame's
    mean confidence vs its largest keypoint error (`spearman_frame`; both should be negative); the mean of the
    frames' mean confidences where the largest keypoint error is <= 10 mm (`confidence_max_le_10mm`, the
    heuristic's per-keypoint distance) and where it is above (`confidence_max_gt_10mm`), with their counts.
    """
    ok = np.isfinite(errors_mm) & np.isfinite(confidence)
    frame_ok = ok.all(axis=1)
    frame_conf, frame_max = confidence[frame_ok].mean(axis=1), errors_mm[frame_ok].max(axis=1)
    good = frame_max <= 10.0

    def rho(a: np.ndarray, b: np.ndarray) -> float | None:
        if a.size < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
            return None
        return round(float(spearmanr(a, b).statistic), 3)

    def mean(values: np.ndarray) -> float | None:
        return round(float(values.mean()), 3) if values.size else None

    return {"spearman_keypoint": rho(confidence[ok], errors_mm[ok]), "spearman_frame": rho(frame_conf, frame_max),
            "confidence_max_le_10mm": mean(frame_conf[good]), "frames_max_le_10mm": int(good.sum()),
            "confidence_max_gt_10mm": mean(frame_conf[~good]), "frames_max_gt_10mm": int((~good).sum())}


CRITERIA = ("mean confidence", "min keypoint confidence", "mean IoU", "views have IoU", "mean 3D distance",
            "max 3D distance")


def criterion(message: str) -> str:
    """The heuristic criterion a failure message of heuristic_verdict is about."""
    return next((c for c in CRITERIA if c in message), message)


def prediction_masks(kind: str, hand_masks: dict[str, np.ndarray], chroma: dict[str, np.ndarray],
                     cameras: Sequence[Camera], keypoints_m: np.ndarray) -> tuple[tuple[np.ndarray | None, ...], bool]:
    """The masks a fit from a prediction ((21, 3) keypoints, metres, world frame) is made against, per camera, and
    whether they include the forearm. kind "gt_hand_masks": the true hand masks (camera name -> (H, W) bool);
    "chroma_key": the chroma-key foreground cut at the predicted wrist, as the loop cuts it."""
    if kind == "gt_hand_masks":
        return tuple(hand_masks[c.name] for c in cameras), False
    if kind != "chroma_key":
        raise ValueError(f"mask kind must be gt_hand_masks or chroma_key, not {kind!r}")
    masks, _, include_forearm = prediction_reference_masks([None] * len(cameras), [chroma.get(c.name) for c in cameras],
                                                           cameras, keypoints_m, "chroma_key")
    return tuple(masks), include_forearm


def heuristic_on_fits(engine: FittingEngine, model: MVNet, data: MVNetDataset,
                      frames: Sequence[FrameRef]) -> dict[str, Any]:
    """Fits from `model`'s predictions (as a round makes them) with the ground-truth hand masks and with the chroma
    key, judged by the paper's heuristic against the predictions; see the module docstring."""
    pred = predict(model, data)
    cameras = list(data.cameras)
    thresholds = HeuristicThresholds()
    rows: dict[str, list[dict[str, Any]]] = {"gt_hand_masks": [], "chroma_key": []}
    for m, frame in enumerate(frames):
        gt = load_ground_truth(frame)
        chroma = load_frame_masks(frame)
        for kind in ("gt_hand_masks", "chroma_key"):
            masks, forearm = prediction_masks(kind, gt.hand_masks, chroma, cameras, pred.keypoints_3d[m])
            obs = FrameObservations.empty(len(cameras))
            obs = FrameObservations(obs.clicks_px, obs.click_weights, masks=masks, masks_include_forearm=forearm,
                                    keypoints_3d=pred.keypoints_3d[m],
                                    keypoint_3d_weights=np.clip(pred.confidence[m], 0, 1))
            fit = engine.fit([obs])[0]
            ious = [float(i) for i in fit.diagnostics.iou_per_view if np.isfinite(i)]
            verdict = heuristic_verdict(pred.confidence[m], ious or [0.0], pred.keypoints_3d[m], fit.keypoints,
                                        thresholds)
            rows[kind].append({"accepted": verdict.accepted, "failed": [criterion(f) for f in verdict.failed],
                               "metrics": verdict.metrics,
                               "vertex_mm": 1000 * float(np.linalg.norm(fit.vertices - gt.vertices, axis=1).mean())})
    out = {}
    for kind, found in rows.items():
        accepted = [r for r in found if r["accepted"]]
        failed: dict[str, int] = {}
        for r in found:
            for reason in r["failed"]:
                failed[reason] = failed.get(reason, 0) + 1

        def median(key: str, scale: float = 1.0, rows_: list[dict[str, Any]] = found) -> float:
            return round(scale * float(np.median([r["metrics"][key] for r in rows_])), 3)

        out[kind] = {"frames": len(found), "accepted": len(accepted),
                     "precision": round(sum(r["vertex_mm"] <= 10 for r in accepted) / len(accepted), 3)
                     if accepted else None,
                     "failed": failed, "mean_iou_median": median("mean_iou"),
                     "mean_distance_mm_median": median("mean_distance_m", 1000),
                     "max_distance_mm_median": median("max_distance_m", 1000),
                     "mean_confidence_median": median("mean_confidence"),
                     "fit_vertex_mm_median": round(float(np.median([r["vertex_mm"] for r in found])), 2)}
    return out


def parse_config(spec: str) -> NetsConfig:
    """A configuration name, optionally with MVNet fields replaced for an experiment:
    "cpu-small-detector:detector_residual=likelihood,sigma_voxels=2" (values parsed as bool "true"/"false", int,
    float or str)."""
    name, _, overrides = spec.partition(":")
    if name not in CONFIGS:
        raise ValueError(f"unknown configuration {name!r}; choose from {sorted(CONFIGS)}")
    fields: dict[str, Any] = {}
    for item in filter(None, overrides.split(",")):
        key, sep, value = item.partition("=")
        if not sep or key not in MVNetConfig.__dataclass_fields__:
            raise ValueError(f"{spec!r}: {item!r} is not FIELD=VALUE of an MVNet configuration field")
        if value.lower() in ("true", "false"):
            fields[key] = value.lower() == "true"
            continue
        for kind in (int, float):
            try:
                fields[key] = kind(value)
                break
            except ValueError:
                continue
        else:
            fields[key] = value
    return get_config(name, **fields)


def run(*, data_dir: Path | None = None, width: int = 640, sequences: int = 8, frames: int = 12, seed: int = 1515,
        configs: Sequence[str] = DEFAULT_CONFIGS, steps: Sequence[int] = DEFAULT_STEPS, threads: int = 1,
        heuristic: bool = True, emit_json: bool = True) -> dict[str, Any]:
    """Measure and return the record (printed as the last stdout line when `emit_json`)."""
    parsed = {c: parse_config(c) for c in configs}
    not_detector = [c for c, cfg in parsed.items() if cfg.mvnet.heatmap_source != "detector"]
    if not_detector:
        raise ValueError(f"configuration(s) {not_detector} are not detector-backed")
    if not steps or any(int(n) < 1 for n in steps):
        raise ValueError(f"steps must be positive step counts, got {list(steps)}")
    if sequences < 4:
        raise ValueError(f"sequences must be >= 4 (three training sequences at least), got {sequences}")
    if frames < HELD_OUT_EVERY:
        raise ValueError(f"frames must be >= {HELD_OUT_EVERY}, got {frames}")
    started = time.perf_counter()
    load_start = [round(x, 2) for x in os.getloadavg()]
    torch.set_num_threads(threads)
    data_dir = Path(data_dir or Path(os.environ.get("TMPDIR", "/tmp")) / "handloop-bench-precision")
    capture = read_capture(ensure_capture(data_dir, width, sequences, frames, seed))
    cameras = list(capture.cameras)
    green = [s for s in capture.sequences if s.split == "train"]
    train_seqs, other_seqs = green[:-2], green[-2:]
    train = [f for s in train_seqs for i, f in enumerate(s.frames) if i % HELD_OUT_EVERY != HELD_OUT_EVERY - 1]
    held = {"same_sequences": [f for s in train_seqs for i, f in enumerate(s.frames)
                               if i % HELD_OUT_EVERY == HELD_OUT_EVERY - 1],
            "other_subjects": [f for s in other_seqs for f in s.frames]}
    cache = DetectionCache(data_dir / "detections")
    side = capture.hand_model.side
    t0 = time.perf_counter()
    detections = {"train": detect_frames(train, cameras, handedness=side, cache=cache)}
    detections.update({k: detect_frames(v, cameras, handedness=side, cache=cache) for k, v in held.items()})
    detect_s = time.perf_counter() - t0
    record: dict[str, Any] = {"lift": {}, "configs": {}}
    engine = FittingEngine(load_hand_model(get_settings().mano_path, side), cameras,
                           FitConfig(weights=LossWeights.later_rounds())) if heuristic else None
    labels = {k: np.stack([load_ground_truth(f).keypoints_3d for f in v]) for k, v in (("train", train), *held.items())}
    for key, found in detections.items():
        lifted = np.stack([d.points_world for d in found])
        record["lift"][key] = keypoint_stats(1000 * np.linalg.norm(lifted - labels[key], axis=-1))
    pose_offsets = learn_detector_offsets(detections["train"], labels["train"], pose=True)
    offsets = replace(pose_offsets, pose=None)  # the constant offsets alone
    record["lift_corrected"] = {  # the lift moved by the keypoint offsets learned from the training frames' labels
        key: keypoint_stats(1000 * np.linalg.norm(offsets.apply(np.stack([d.points_world for d in found]))
                                                  - labels[key], axis=-1)) for key, found in detections.items()}
    record["lift_pose_corrected"] = {  # and by the pose term after them (keypoint_offsets.PoseCorrection)
        key: keypoint_stats(1000 * np.linalg.norm(pose_offsets.apply(np.stack([d.points_world for d in found]))
                                                  - labels[key], axis=-1)) for key, found in detections.items()}
    record["keypoint_offsets_mm"] = np.round(1000 * offsets.offsets_m, 2).tolist()
    for name in configs:
        config = parsed[name]
        use = (pose_offsets if config.mvnet.detector_pose_correction else offsets) if config.mvnet.detector_offsets \
            else None
        sets = {k: build_mvnet_dataset(capture, v, config.mvnet, detections=detections[k], detector_offsets=use)
                for k, v in (("train", train), *held.items())}
        torch.manual_seed(seed)
        untrained = MVNet(config.mvnet).eval()
        if config.mvnet.detector_offsets:
            untrained.set_keypoint_offsets(use)
        result: dict[str, Any] = {"untrained": {k: mvnet_stats(untrained, sets[k]) for k in held}}
        for n in steps:
            load_before = os.getloadavg()[0]
            t1 = time.perf_counter()
            out = data_dir / "checkpoints" / (re.sub(r"[^A-Za-z0-9_.-]", "_", name) + f"-steps{n}")
            trained = train_mvnet(sets["train"], config, float("inf"), out, resume=False, max_steps=int(n),
                                  seed=seed).model
            seconds = time.perf_counter() - t1
            result[f"steps_{n}"] = {**{k: mvnet_stats(trained, sets[k]) for k in ("train", *held)},
                                    "s_per_step": round(seconds / n, 3),
                                    "load": [round(load_before, 2), round(os.getloadavg()[0], 2)]}
        if heuristic:
            result["heuristic"] = {"steps": int(steps[-1]), **{
                k: heuristic_on_fits(engine, trained, sets[k], held[k]) for k in held}}
        record["configs"][name] = result
    record.update({"train_frames": len(train), **{f"{k}_frames": len(v) for k, v in held.items()},
                   "detect_s": round(detect_s, 1)})
    settings = {"heuristic": heuristic, "width_px": width, "sequences": sequences, "frames_per_sequence": frames,
                "seed": seed,
                "configs": list(configs), "steps": [int(n) for n in steps], "torch_threads": threads,
                "capture": str(capture.root), "load_average_at_start": load_start,
                "load_average_at_end": [round(x, 2) for x in os.getloadavg()]}
    if emit_json:
        return emit("mvnet-precision", record, settings, started)
    return {**record, "settings": settings}
