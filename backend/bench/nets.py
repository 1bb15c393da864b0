"""Benchmark of the networks (`handloop bench nets`): train `cpu-small` on synthetic green-screen frames within
a fixed budget and evaluate on held-out subjects in front of other backgrounds.

Full run: 16 sequences x 60 frames at 320 px (12 training sequences = 720 frames of 6 subjects, 4
evaluation sequences = 240 frames of 2 other subjects); HandSegNet 180 s (on 240 of the training frames),
each MVNet 400 s of training (the soft-argmax network only for the confidence comparison).
--quick: 8 sequences x 4 frames at 160 px, 10 s / 15 s budgets. The synthetic capture is cached in the
data folder and reused when its settings match (synthesis is not training time).

Reported: MVNet mean keypoint error (mm) and 3D PCK AUC over 0-50 mm through the whole prediction path
(HandSegNet masks -> triangulated hand centre -> MVNet); the same with crops centred by the ground-truth
masks; HandSegNet IoU on the evaluation views; sparsification curves of the score-volume and
soft-argmax networks with their oracles and AUSE (PNG + numbers); training minutes; inference ms per
8-view frame (HandSegNet both passes + localisation + cropping + MVNet, decoded images in).
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from backend.bench.common import emit
from backend.settings import get_settings
from workers.capture.reader import load_frame_images, load_ground_truth, read_capture
from workers.nets.configs import get_config
from workers.nets.data import build_handseg_dataset, build_mvnet_dataset, hand_center_from_labels
from workers.nets.handsegnet import mask_iou
from workers.nets.predict import predict_keypoints, predict_masks
from workers.nets.sparsification import plot_sparsification, sparsification
from workers.nets.train import TrainProgress, train_handsegnet, train_mvnet
from workers.synth.generator import generate_capture
from workers.synth.plan import SynthConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class NetsBenchSize:
    sequences: int
    frames: int
    width_px: int
    handseg_budget_s: float
    mvnet_budget_s: float
    handseg_max_frames: int


SIZES: dict[bool, NetsBenchSize] = {
    False: NetsBenchSize(sequences=16, frames=60, width_px=320, handseg_budget_s=180.0, mvnet_budget_s=400.0,
                         handseg_max_frames=240),
    True: NetsBenchSize(sequences=8, frames=4, width_px=160, handseg_budget_s=10.0, mvnet_budget_s=15.0,
                        handseg_max_frames=24),
}
PCK_MAX_MM = 50.0


def pck_auc(errors_mm: np.ndarray, max_mm: float = PCK_MAX_MM, steps: int = 101) -> float:
    """Area under the 3D PCK curve over thresholds 0..max_mm, normalised to [0, 1]."""
    thresholds = np.linspace(0, max_mm, steps)
    pck = np.array([(errors_mm <= t).mean() for t in thresholds])
    return float(np.trapezoid(pck, thresholds) / max_mm)


def ensure_capture(data_dir: Path, size: NetsBenchSize, seed: int) -> Path:
    """The benchmark's synthetic capture: reused from `data_dir` when written with the same settings."""


    root = data_dir / f"synth-s{size.sequences}-f{size.frames}-w{size.width_px}-seed{seed}"
    header = root / "capture.json"
    want = {"seed": seed, "width_px": size.width_px, "sequences": size.sequences, "frames": size.frames}
    if header.is_file():
        generator = json.loads(header.read_text()).get("generator", {})
        expected_images = size.sequences * size.frames * 8
        if all(generator.get(k) == v for k, v in want.items()) and \
                len(list(root.glob("sequences/*/images/*/*"))) >= expected_images:
            log.info("reusing the synthetic capture %s", root)
            return root
    settings = get_settings()
    config = SynthConfig(num_sequences=size.sequences, frames_per_sequence=size.frames, seed=seed,
                         width_px=size.width_px)
    with tqdm(total=size.sequences * size.frames, unit="frame", desc="synth", file=sys.stderr) as bar:
        generate_capture(root, config, force=True, mano_path=settings.mano_path, progress=bar.update)
    return root


def split_frames(capture: Any) -> tuple[list[Any], list[Any]]:
    """Training frames (green-screen sequences) and evaluation frames of subjects never trained on."""
    train_seqs = [s for s in capture.sequences if s.split == "train"]
    train_subjects = {s.subject_id for s in train_seqs}
    eval_seqs = [s for s in capture.sequences if s.split == "evaluation" and s.subject_id not in train_subjects]
    if not train_seqs or not eval_seqs:
        raise ValueError("the capture needs training sequences and evaluation sequences of other subjects")
    return [f for s in train_seqs for f in s.frames], [f for s in eval_seqs for f in s.frames]


def run(*, quick: bool = False, data_dir: Path | None = None, out_dir: Path | None = None, seed: int = 0,
        config_name: str = "cpu-small", threads: int = 1, emit_json: bool = True) -> dict[str, Any]:
    """Run the benchmark and return its record (printed as the last stdout line when `emit_json`).

    `threads` sets torch's CPU threads (default 1: on a shared machine more threads than free cores
    slow convolutions several-fold).
    """


    started = time.perf_counter()
    torch.set_num_threads(threads)
    load_start = [round(x, 2) for x in os.getloadavg()]
    size = SIZES[quick]
    config = get_config(config_name)
    data_dir = Path(data_dir or Path(os.environ.get("TMPDIR", "/tmp")) / "handloop-bench-nets")
    out_dir = Path(out_dir or data_dir / f"run-{'quick' if quick else 'full'}-{time.strftime('%Y%m%d-%H%M%S')}")
    out_dir.mkdir(parents=True, exist_ok=True)
    capture = read_capture(ensure_capture(data_dir, size, seed))
    cameras = list(capture.cameras)
    train_frames, eval_frames = split_frames(capture)
    log.info("%d training frames, %d evaluation frames (held-out subjects)", len(train_frames), len(eval_frames))

    with tqdm(total=len(train_frames), desc="crops", file=sys.stderr) as bar:
        mv_data = build_mvnet_dataset(capture, train_frames, config.mvnet, progress=bar.update)
    step = max(1, len(train_frames) // size.handseg_max_frames)
    with tqdm(total=len(train_frames[::step]), desc="masks", file=sys.stderr) as bar:
        seg_data = build_handseg_dataset(capture, train_frames[::step], progress=bar.update)

    def bar_progress(bar: Any) -> Any:
        def update(p: TrainProgress) -> None:
            bar.n = min(bar.total, round(p.seconds))
            bar.set_postfix(step=p.step, loss=f"{p.loss:.4g}", refresh=False)
            bar.refresh()
        return update

    ckpt = out_dir / "checkpoints" / "round-000"
    trained: dict[str, Any] = {}
    train_s: dict[str, float] = {}
    train_steps: dict[str, int] = {}
    train_load: dict[str, list[float]] = {}
    jobs = [("handsegnet", size.handseg_budget_s), ("scorevolume", size.mvnet_budget_s),
            ("softargmax", size.mvnet_budget_s)]
    for name, budget in jobs:
        load_before = os.getloadavg()[0]
        with tqdm(total=round(budget), desc=f"train {name}", unit="s", file=sys.stderr) as bar:
            if name == "handsegnet":
                result = train_handsegnet(seg_data, config, budget, ckpt, resume=False, seed=seed,
                                          progress=bar_progress(bar))
            else:
                mv_config = get_config(config_name, loss=name)
                result = train_mvnet(mv_data, mv_config, budget, ckpt / name, resume=False, seed=seed,
                                     progress=bar_progress(bar))
        trained[name], train_s[name] = result.model, result.metadata["train_seconds"]
        train_steps[name] = int(result.metadata["steps"])
        # 1-minute load average when the phase started and ended: tells compute starvation from a bad model.
        train_load[name] = [round(load_before, 2), round(os.getloadavg()[0], 2)]
    torch.set_grad_enabled(False)

    ious, errors, errors_gt_center, confidences, failures, times_ms = [], {}, {}, {}, 0, []
    center_errors_mm: list[float] = []
    confidences_gt_center: dict[str, list[float]] = {}
    for name in ("scorevolume", "softargmax"):
        errors[name], errors_gt_center[name], confidences[name], confidences_gt_center[name] = [], [], [], []
    for frame in tqdm(eval_frames, desc="evaluate", file=sys.stderr):
        views = load_frame_images(frame, cameras)
        ordered = [views[c.name] for c in cameras]
        gt = load_ground_truth(frame)
        t0 = time.perf_counter()
        masks = predict_masks(trained["handsegnet"], ordered, cameras)
        if masks.location is not None:
            pred = predict_keypoints(trained["scorevolume"], [ordered], cameras, masks.location.center_world[None],
                                     batch_frames=1)
        times_ms.append(1000 * (time.perf_counter() - t0))
        for cam, prob in zip(cameras, masks.probabilities, strict=True):
            if gt.hand_masks[cam.name].any():
                ious.append(mask_iou(prob > trained["handsegnet"].config.threshold, gt.hand_masks[cam.name]))
        gt_center = hand_center_from_labels([gt.hand_masks[c.name] for c in cameras], gt.keypoints_3d, cameras)
        if masks.location is not None:
            center_errors_mm.append(1000 * float(np.linalg.norm(masks.location.center_world - gt_center)))
        for name in ("scorevolume", "softargmax"):
            model = trained[name]
            if masks.location is not None:
                if name != "scorevolume":
                    pred = predict_keypoints(model, [ordered], cameras, masks.location.center_world[None],
                                             batch_frames=1)
                errors[name].append(1000 * np.linalg.norm(pred.keypoints_3d[0] - gt.keypoints_3d, axis=-1))
                confidences[name].append(pred.sample_confidence[0])
            pred_gt = predict_keypoints(model, [ordered], cameras, gt_center[None], batch_frames=1)
            confidences_gt_center[name].append(pred_gt.sample_confidence[0])
            errors_gt_center[name].append(1000 * np.linalg.norm(pred_gt.keypoints_3d[0] - gt.keypoints_3d, axis=-1))
        failures += masks.location is None

    # Sparsification on the whole path; on ground-truth-centred crops when too few frames were localised.
    sparse_path = "handsegnet" if len(errors["scorevolume"]) >= 10 else "gt_center"
    curves = {}
    record: dict[str, Any] = {}
    for name in ("scorevolume", "softargmax"):
        err = np.asarray(errors[name]) if errors[name] else np.full((1, 21), np.nan)
        err_gt = np.asarray(errors_gt_center[name])
        if sparse_path == "handsegnet":
            curves[name] = sparsification(err.mean(axis=1), np.asarray(confidences[name]))
        else:
            curves[name] = sparsification(err_gt.mean(axis=1), np.asarray(confidences_gt_center[name]))
        prefix = "mvnet" if name == "scorevolume" else "mvnet_softargmax"
        record[f"{prefix}_keypoint_mm"] = round(float(np.mean(err)), 2) if errors[name] else None
        record[f"{prefix}_auc"] = round(pck_auc(err.ravel()), 4) if errors[name] else None
        record[f"{prefix}_keypoint_mm_gt_center"] = round(float(np.mean(err_gt)), 2)
        record[f"{prefix}_auc_gt_center"] = round(pck_auc(err_gt.ravel()), 4)
    plot = plot_sparsification(curves, out_dir / "sparsification.png") if curves else None
    record.update({
        "handsegnet_iou": round(float(np.mean(ious)), 4) if ious else None,
        "handsegnet_iou_views": len(ious),
        "ause_scorevolume": round(curves["scorevolume"].ause, 3) if "scorevolume" in curves else None,
        "ause_softargmax": round(curves["softargmax"].ause, 3) if "softargmax" in curves else None,
        "ause_relative_scorevolume": round(curves["scorevolume"].ause / curves["scorevolume"].curve[0], 4)
        if "scorevolume" in curves else None,
        "ause_relative_softargmax": round(curves["softargmax"].ause / curves["softargmax"].curve[0], 4)
        if "softargmax" in curves else None,
        "sparsification": {name: {"fractions": c.fractions[::5].round(3).tolist(),
                                  "curve_mm": c.curve[::5].round(2).tolist(),
                                  "oracle_mm": c.oracle[::5].round(2).tolist()} for name, c in curves.items()},
        "sparsification_png": str(plot) if plot else None,
        "sparsification_path": sparse_path,
        "train_minutes": round((train_s["handsegnet"] + train_s["scorevolume"]) / 60, 2),
        "train_minutes_mvnet": round(train_s["scorevolume"] / 60, 2),
        "train_minutes_handsegnet": round(train_s["handsegnet"] / 60, 2),
        "train_minutes_softargmax": round(train_s["softargmax"] / 60, 2),
        "inference_ms": round(float(np.mean(times_ms)), 1),
        "inference_ms_median": round(float(np.median(times_ms)), 1),
        "localisation_failures": failures,
        "hand_center_error_mm": round(float(np.mean(center_errors_mm)), 1) if center_errors_mm else None,
        "hand_center_error_mm_median": round(float(np.median(center_errors_mm)), 1) if center_errors_mm else None,
        "train_steps_handsegnet": train_steps["handsegnet"],
        "train_steps_mvnet": train_steps["scorevolume"],
        "train_steps_softargmax": train_steps["softargmax"],
        "train_load_average": train_load,
        "train_frames": len(train_frames),
        "handsegnet_train_frames": len(train_frames[::step]),
        "eval_frames": len(eval_frames),
        "checkpoints": str(ckpt),
    })
    bench_settings = {
        "quick": quick, "config": config_name, "seed": seed, "sequences": size.sequences,
        "frames_per_sequence": size.frames, "width_px": size.width_px,
        "handseg_budget_s": size.handseg_budget_s, "mvnet_budget_s": size.mvnet_budget_s,
        "device": "cuda" if torch.cuda.is_available() else "cpu", "torch_threads": threads,
        "load_average_at_end": [round(x, 2) for x in os.getloadavg()], "load_average_at_start": load_start,
        "capture": str(capture.root),
    }
    if emit_json:
        return emit("nets", record, bench_settings, started)
    return {**record, "settings": bench_settings}
