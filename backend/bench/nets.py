"""Benchmark of the networks (`handloop bench nets`): train `cpu-small` on synthetic green-screen frames within
a fixed budget and evaluate on held-out subjects in front of other backgrounds.

Full run: 16 sequences x 60 frames at 320 px (12 training sequences = 720 frames of 6 subjects, 4
evaluation sequences = 240 frames of 2 other subjects); HandSegNet 180 s (on 240 of the training frames),
each MVNet 400 s of training (the soft-argmax network only for the confidence comparison); `--mvnet-steps N`
trains every MVNet for exactly N steps instead (figures that do not depend on the machine's load).
--quick: 8 sequences x 4 frames at 160 px, 10 s / 15 s budgets. The synthetic capture is cached in the
data folder and reused when its settings match (synthesis is not training time).

`mvnet`: "paper" (the paper-only networks), "detector" (the detector-backed MVNet, `cpu-small-detector`, with
HandSegNet for the whole path) or "both" (side by side). The detector-backed MVNet trains on the training frames'
detections (found with their chroma-key masks, detected once and cached in the data folder) and is evaluated
through HandSegNet masks -> detector (inside the masks) -> grid centre from the lifted keypoints -> MVNet, and
with ground-truth-centred crops whose detections were found with the ground-truth hand masks (`*_gt_center`);
its keys carry the prefix `detector_mvnet_`, and `side_by_side` pairs them with the paper-only ones. Where the
detector's model files are missing, the paper-only networks alone are measured and `detector_status` says why.

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
from dataclasses import dataclass, replace
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
from workers.nets.detections import DetectionCache, detect_frames, detector_backed, learn_detector_offsets
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


MVNET_CHOICES = ("paper", "detector", "both")


def run(*, quick: bool = False, data_dir: Path | None = None, out_dir: Path | None = None, seed: int = 0,
        config_name: str = "cpu-small", threads: int = 1, emit_json: bool = True, mvnet: str = "both",
        detector_config_name: str = "cpu-small-detector", frames_per_sequence: int | None = None,
        mvnet_steps: int | None = None) -> dict[str, Any]:
    """Run the benchmark and return its record (printed as the last stdout line when `emit_json`).

    `threads` sets torch's CPU threads (default 1: on a shared machine more threads than free cores
    slow convolutions several-fold). `mvnet`: which MVNet(s) to train and measure (MVNET_CHOICES).
    `frames_per_sequence` replaces the size's frame count (same budgets; a capture of its own).
    `mvnet_steps`: train every MVNet for exactly this many steps instead of the size's time budget (figures that
    do not depend on the machine's load; the cosine schedule runs over the steps).
    """


    if mvnet not in MVNET_CHOICES:
        raise ValueError(f"mvnet must be one of {MVNET_CHOICES}, got {mvnet!r}")
    if mvnet_steps is not None and mvnet_steps < 1:
        raise ValueError(f"mvnet_steps must be >= 1, got {mvnet_steps}")
    started = time.perf_counter()
    torch.set_num_threads(threads)
    load_start = [round(x, 2) for x in os.getloadavg()]
    size = SIZES[quick]
    if frames_per_sequence is not None:
        if frames_per_sequence < 1:
            raise ValueError(f"frames_per_sequence must be >= 1, got {frames_per_sequence}")
        size = replace(size, frames=frames_per_sequence)
    config = get_config(config_name)
    detector_status = None
    det_config = None
    if mvnet in ("detector", "both"):
        det_config, detector_status = detector_backed(get_config(detector_config_name))
        if detector_status is not None:
            sys.stderr.write(f"bench nets: {detector_status}; measuring the paper-only MVNet alone\n")
            det_config = None
    paper_nets = ("scorevolume", "softargmax") if mvnet in ("paper", "both") or det_config is None else ()
    data_dir = Path(data_dir or Path(os.environ.get("TMPDIR", "/tmp")) / "handloop-bench-nets")
    out_dir = Path(out_dir or data_dir / f"run-{'quick' if quick else 'full'}-{time.strftime('%Y%m%d-%H%M%S')}")
    out_dir.mkdir(parents=True, exist_ok=True)
    capture = read_capture(ensure_capture(data_dir, size, seed))
    cameras = list(capture.cameras)
    hand = capture.hand_model.side
    train_frames, eval_frames = split_frames(capture)
    log.info("%d training frames, %d evaluation frames (held-out subjects)", len(train_frames), len(eval_frames))
    cache = DetectionCache(data_dir / "detections")

    datasets: dict[str, Any] = {}
    if paper_nets:
        with tqdm(total=len(train_frames), desc="crops", file=sys.stderr) as bar:
            datasets["paper"] = build_mvnet_dataset(capture, train_frames, config.mvnet, progress=bar.update)
    detection_s = 0.0
    if det_config is not None:
        t0 = time.perf_counter()
        with tqdm(total=len(train_frames), desc="detect (training frames, cached)", file=sys.stderr) as bar:
            train_detections = detect_frames(train_frames, cameras, handedness=hand, cache=cache, progress=bar.update)
        detection_s = time.perf_counter() - t0
        offsets = None
        if det_config.mvnet.detector_offsets:  # learned from the training frames' labels, as a round does
            offsets = learn_detector_offsets(train_detections, np.stack([load_ground_truth(f).keypoints_3d
                                                                         for f in train_frames]),
                                             pose=det_config.mvnet.detector_pose_correction)
        with tqdm(total=len(train_frames), desc="crops (detector)", file=sys.stderr) as bar:
            datasets["detector"] = build_mvnet_dataset(capture, train_frames, det_config.mvnet,
                                                       detections=train_detections, detector_offsets=offsets,
                                                       progress=bar.update)
    step = max(1, len(train_frames) // size.handseg_max_frames)
    with tqdm(total=len(train_frames[::step]), desc="masks", file=sys.stderr) as bar:
        seg_data = build_handseg_dataset(capture, train_frames[::step], progress=bar.update)

    def bar_progress(bar: Any) -> Any:
        def update(p: TrainProgress) -> None:
            bar.n = p.step if bar.unit == "step" else min(bar.total, round(p.seconds))
            bar.set_postfix(step=p.step, loss=f"{p.loss:.4g}", refresh=False)
            bar.refresh()
        return update

    ckpt = out_dir / "checkpoints" / "round-000"
    trained: dict[str, Any] = {}
    train_s: dict[str, float] = {}
    train_steps: dict[str, int] = {}
    train_load: dict[str, list[float]] = {}
    # A step budget trains for exactly that many steps, whatever the time (budget inf, max_steps).
    mvnet_budget_s = size.mvnet_budget_s if mvnet_steps is None else float("inf")
    jobs = [("handsegnet", size.handseg_budget_s)] + [(name, mvnet_budget_s) for name in paper_nets]
    if det_config is not None:
        jobs.append(("detector", mvnet_budget_s))
    for name, budget in jobs:
        load_before = os.getloadavg()[0]
        steps_only = name != "handsegnet" and mvnet_steps is not None
        with tqdm(total=round(budget) if not steps_only else mvnet_steps, desc=f"train {name}",
                  unit="step" if steps_only else "s", file=sys.stderr) as bar:
            if name == "handsegnet":
                result = train_handsegnet(seg_data, config, budget, ckpt, resume=False, seed=seed,
                                          progress=bar_progress(bar))
            elif name == "detector":
                result = train_mvnet(datasets["detector"], det_config, budget, ckpt / name, resume=False, seed=seed,
                                     progress=bar_progress(bar), max_steps=mvnet_steps)
            else:
                mv_config = get_config(config_name, loss=name)
                result = train_mvnet(datasets["paper"], mv_config, budget, ckpt / name, resume=False, seed=seed,
                                     progress=bar_progress(bar), max_steps=mvnet_steps)
        trained[name], train_s[name] = result.model, result.metadata["train_seconds"]
        train_steps[name] = int(result.metadata["steps"])
        # 1-minute load average when the phase started and ended: tells compute starvation from a bad model.
        train_load[name] = [round(load_before, 2), round(os.getloadavg()[0], 2)]
    torch.set_grad_enabled(False)

    nets = [*paper_nets, *(["detector"] if det_config is not None else [])]
    ious, failures, times_ms = [], 0, []
    errors: dict[str, list[np.ndarray]] = {n: [] for n in nets}
    errors_gt_center: dict[str, list[np.ndarray]] = {n: [] for n in nets}
    confidences: dict[str, list[float]] = {n: [] for n in nets}
    confidences_gt_center: dict[str, list[float]] = {n: [] for n in nets}
    center_errors_mm: list[float] = []
    det_times_ms: list[float] = []
    det_failures = 0
    det_center_errors_mm: list[float] = []
    lift_errors: list[np.ndarray] = []
    lift_errors_gt_masks: list[np.ndarray] = []
    threshold = trained["handsegnet"].config.threshold
    for frame in tqdm(eval_frames, desc="evaluate", file=sys.stderr):
        views = load_frame_images(frame, cameras)
        ordered = [views[c.name] for c in cameras]
        gt = load_ground_truth(frame)
        t0 = time.perf_counter()
        masks = predict_masks(trained["handsegnet"], ordered, cameras)
        t_masks = time.perf_counter() - t0
        pred = None
        if masks.location is not None and "scorevolume" in trained:
            pred = predict_keypoints(trained["scorevolume"], [ordered], cameras, masks.location.center_world[None],
                                     batch_frames=1)
        times_ms.append(1000 * (time.perf_counter() - t0))
        for cam, prob in zip(cameras, masks.probabilities, strict=True):
            if gt.hand_masks[cam.name].any():
                ious.append(mask_iou(prob > threshold, gt.hand_masks[cam.name]))
        gt_masks = [gt.hand_masks[c.name] for c in cameras]
        gt_center = hand_center_from_labels(gt_masks, gt.keypoints_3d, cameras)
        if masks.location is not None:
            center_errors_mm.append(1000 * float(np.linalg.norm(masks.location.center_world - gt_center)))
        for name in paper_nets:
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
        if det_config is not None:
            # The whole path: HandSegNet's masks (timed above) -> detector inside them -> centre -> MVNet.
            t1 = time.perf_counter()
            binary = [p > threshold for p in masks.probabilities]
            found = detect_frames([frame], cameras, handedness=hand, images=lambda _f, v=ordered: v,
                                  masks=lambda _f, b=binary: b)[0]
            center = found.center_world()
            if center is None and masks.location is not None:
                center = masks.location.center_world
            if center is not None:
                pred_d = predict_keypoints(trained["detector"], [ordered], cameras, center[None], batch_frames=1,
                                           detections=[found])
            det_times_ms.append(1000 * (time.perf_counter() - t1 + t_masks))
            if center is not None:
                det_center_errors_mm.append(1000 * float(np.linalg.norm(center - gt_center)))
                errors["detector"].append(1000 * np.linalg.norm(pred_d.keypoints_3d[0] - gt.keypoints_3d, axis=-1))
                confidences["detector"].append(pred_d.sample_confidence[0])
            else:
                det_failures += 1
            lift_errors.append(1000 * np.linalg.norm(found.points_world - gt.keypoints_3d, axis=-1))
            # MVNet given the right place: detections inside the ground-truth hand masks, crops at the gt centre.
            found_gt = detect_frames([frame], cameras, handedness=hand, images=lambda _f, v=ordered: v,
                                     masks=lambda _f, g=gt_masks: g, masks_label="ground_truth", cache=cache)[0]
            lift_errors_gt_masks.append(1000 * np.linalg.norm(found_gt.points_world - gt.keypoints_3d, axis=-1))
            pred_dg = predict_keypoints(trained["detector"], [ordered], cameras, gt_center[None], batch_frames=1,
                                        detections=[found_gt])
            confidences_gt_center["detector"].append(pred_dg.sample_confidence[0])
            errors_gt_center["detector"].append(1000 * np.linalg.norm(pred_dg.keypoints_3d[0] - gt.keypoints_3d,
                                                                      axis=-1))

    # Sparsification on the whole path; on ground-truth-centred crops when too few frames were localised.
    curves = {}
    sparse_paths = {}
    record: dict[str, Any] = {}
    prefixes = {"scorevolume": "mvnet", "softargmax": "mvnet_softargmax", "detector": "detector_mvnet"}
    for name in nets:
        err = np.asarray(errors[name]) if errors[name] else np.full((1, 21), np.nan)
        err_gt = np.asarray(errors_gt_center[name])
        sparse_paths[name] = "whole_path" if len(errors[name]) >= 10 else "gt_center"
        if sparse_paths[name] == "whole_path":
            curves[name] = sparsification(err.mean(axis=1), np.asarray(confidences[name]))
        else:
            curves[name] = sparsification(err_gt.mean(axis=1), np.asarray(confidences_gt_center[name]))
        prefix = prefixes[name]
        record[f"{prefix}_keypoint_mm"] = round(float(np.mean(err)), 2) if errors[name] else None
        record[f"{prefix}_keypoint_mm_median"] = round(float(np.median(err)), 2) if errors[name] else None
        record[f"{prefix}_auc"] = round(pck_auc(err.ravel()), 4) if errors[name] else None
        record[f"{prefix}_keypoint_mm_gt_center"] = round(float(np.mean(err_gt)), 2)
        record[f"{prefix}_auc_gt_center"] = round(pck_auc(err_gt.ravel()), 4)
    for name in ("scorevolume", "softargmax", "detector"):
        prefix = prefixes[name]
        for key in ("keypoint_mm", "keypoint_mm_median", "auc", "keypoint_mm_gt_center", "auc_gt_center"):
            record.setdefault(f"{prefix}_{key}", None)
    plot = plot_sparsification(curves, out_dir / "sparsification.png") if curves else None

    def ause(name: str, relative: bool = False) -> float | None:
        if name not in curves:
            return None
        c = curves[name]
        return round(c.ause / c.curve[0], 4) if relative else round(c.ause, 3)

    def mean_or_none(values: list[float], digits: int = 1, median: bool = False) -> float | None:
        return round(float(np.median(values) if median else np.mean(values)), digits) if values else None

    def finite_stat(errs: list[np.ndarray], fn: Any) -> float | None:
        flat = np.concatenate([e[np.isfinite(e)] for e in errs]) if errs else np.array([])
        return round(float(fn(flat)), 2) if flat.size else None

    record.update({
        "handsegnet_iou": round(float(np.mean(ious)), 4) if ious else None,
        "handsegnet_iou_views": len(ious),
        "ause_scorevolume": ause("scorevolume"),
        "ause_softargmax": ause("softargmax"),
        "ause_detector": ause("detector"),
        "ause_relative_scorevolume": ause("scorevolume", True),
        "ause_relative_softargmax": ause("softargmax", True),
        "ause_relative_detector": ause("detector", True),
        "sparsification": {name: {"fractions": c.fractions[::5].round(3).tolist(),
                                  "curve_mm": c.curve[::5].round(2).tolist(),
                                  "oracle_mm": c.oracle[::5].round(2).tolist()} for name, c in curves.items()},
        "sparsification_png": str(plot) if plot else None,
        "sparsification_path": sparse_paths.get("scorevolume", sparse_paths.get("detector")),
        "sparsification_paths": sparse_paths,
        "train_minutes": round((train_s["handsegnet"] + train_s.get("scorevolume", 0.0)) / 60, 2),
        "train_minutes_mvnet": round(train_s["scorevolume"] / 60, 2) if "scorevolume" in train_s else None,
        "train_minutes_handsegnet": round(train_s["handsegnet"] / 60, 2),
        "train_minutes_softargmax": round(train_s["softargmax"] / 60, 2) if "softargmax" in train_s else None,
        "train_minutes_detector_mvnet": round(train_s["detector"] / 60, 2) if "detector" in train_s else None,
        "inference_ms": mean_or_none(times_ms) if paper_nets else None,
        "inference_ms_median": mean_or_none(times_ms, median=True) if paper_nets else None,
        "localisation_failures": failures,
        "hand_center_error_mm": mean_or_none(center_errors_mm),
        "hand_center_error_mm_median": mean_or_none(center_errors_mm, median=True),
        "train_steps_handsegnet": train_steps["handsegnet"],
        "train_steps_mvnet": train_steps.get("scorevolume"),
        "train_steps_softargmax": train_steps.get("softargmax"),
        "train_steps_detector_mvnet": train_steps.get("detector"),
        "train_load_average": train_load,
        "train_frames": len(train_frames),
        "handsegnet_train_frames": len(train_frames[::step]),
        "eval_frames": len(eval_frames),
        "checkpoints": str(ckpt),
        "detector_status": detector_status,
        # The detector-backed path: HandSegNet + detection + lift + MVNet per frame; its own centre and failures.
        "detector_mvnet_inference_ms": mean_or_none(det_times_ms),
        "detector_mvnet_inference_ms_median": mean_or_none(det_times_ms, median=True),
        "detector_mvnet_localisation_failures": det_failures if det_config is not None else None,
        "detector_mvnet_hand_center_error_mm": mean_or_none(det_center_errors_mm),
        "detector_mvnet_hand_center_error_mm_median": mean_or_none(det_center_errors_mm, median=True),
        # The lift alone (no MVNet), over the keypoints it lifted: what MVNet's 3D stage starts from.
        "detector_lift_keypoint_mm": finite_stat(lift_errors, np.mean),
        "detector_lift_keypoint_mm_median": finite_stat(lift_errors, np.median),
        "detector_lift_fraction": round(float(np.mean([np.isfinite(e).mean() for e in lift_errors])), 4)
        if lift_errors else None,
        "detector_lift_keypoint_mm_gt_masks": finite_stat(lift_errors_gt_masks, np.mean),
        "detector_lift_keypoint_mm_median_gt_masks": finite_stat(lift_errors_gt_masks, np.median),
        "detection_train_s": round(detection_s, 1) if det_config is not None else None,
    })
    record["side_by_side"] = {
        metric: {"paper": record[paper_key], "detector": record[det_key]}
        for metric, paper_key, det_key in (
            ("keypoint_mm", "mvnet_keypoint_mm", "detector_mvnet_keypoint_mm"),
            ("keypoint_mm_median", "mvnet_keypoint_mm_median", "detector_mvnet_keypoint_mm_median"),
            ("auc", "mvnet_auc", "detector_mvnet_auc"),
            ("keypoint_mm_gt_center", "mvnet_keypoint_mm_gt_center", "detector_mvnet_keypoint_mm_gt_center"),
            ("auc_gt_center", "mvnet_auc_gt_center", "detector_mvnet_auc_gt_center"),
            ("inference_ms", "inference_ms", "detector_mvnet_inference_ms"),
            ("ause", "ause_scorevolume", "ause_detector"),
            ("ause_relative", "ause_relative_scorevolume", "ause_relative_detector"),
            ("localisation_failures", "localisation_failures", "detector_mvnet_localisation_failures"),
            ("hand_center_error_mm", "hand_center_error_mm", "detector_mvnet_hand_center_error_mm"),
            ("train_steps", "train_steps_mvnet", "train_steps_detector_mvnet"),
        )}
    bench_settings = {
        "quick": quick, "config": config_name, "seed": seed, "sequences": size.sequences,
        "frames_per_sequence": size.frames, "width_px": size.width_px,
        "handseg_budget_s": size.handseg_budget_s,
        "mvnet_budget_s": size.mvnet_budget_s if mvnet_steps is None else None, "mvnet_steps": mvnet_steps,
        "device": "cuda" if torch.cuda.is_available() else "cpu", "torch_threads": threads,
        "load_average_at_end": [round(x, 2) for x in os.getloadavg()], "load_average_at_start": load_start,
        "capture": str(capture.root), "mvnet": mvnet,
        "detector_config": det_config.name if det_config is not None else None,
    }
    if emit_json:
        return emit("nets", record, bench_settings, started)
    return {**record, "settings": bench_settings}
