"""`handloop bench realrig`: the first hour of a lab on a real recording (../shared/realdata/handpose3d).

What a lab does, with handloop's own entry points: the rig's calibration (board-square units, written as OpenCV
FileStorage files) converted as read (`--units m`: a 12.5 m rig), the videos assembled, the calibration check run
(calibration-free detector keypoints): it must flag the scale and give the factor that makes the hand adult-sized;
the calibration converted again with that factor (`--scale`), assembled, and every frame pre-annotated as round 0
does (the detector on the working copies, its lift, the detector fit). No ground truth exists: the figures are
self-consistency (the issue's targets in parentheses):
- found_and_fitted: frames whose hand was found, lifted (>= MIN_LIFTED_KEYPOINTS) and fitted (>= 0.95);
- epipolar_median_px: the two views' detector keypoints, median symmetric epipolar distance (<= 5 px);
- fit_residual_median_frac: the fit's keypoints projected against the detector keypoints it used, median over
  keypoints and views, as a fraction of the image width (<= 0.01);
- scale factor: found on the wrongly scaled rig, against `reference_factor`, the factor that gives the lifted hand
  the hand model's own (adult, mean-shape) bone lengths at the corrected scale (within 20 %).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from backend.bench.common import emit
from backend.bench.realdata import handpose3d_dir, link_handpose3d_videos, write_handpose3d_opencv
from backend.settings import get_settings
from workers.capture import read_capture
from workers.capture.assemble import assemble_capture
from workers.capture.working import load_working_images, working_cameras
from workers.detector import detect_frame, detector_status
from workers.detector.usable import used_detections
from workers.fitting.engine import FittingEngine
from workers.fitting.reweight import fit_reweighted
from workers.geometry.camera import Camera
from workers.geometry.epipolar import symmetric_epipolar_distances
from workers.geometry.projection import project_points
from workers.handmodel.layer import HandLayer
from workers.handmodel.loading import load_hand_model
from workers.rigs.check import check_capture
from workers.rigs.formats import convert
from workers.tasks.detection_inputs import SOURCE as DETECTOR_SOURCE
from workers.tasks.detection_inputs import detection_record, lifted_count, observations_from_detection
from workers.tasks.fits import fit_config_from_settings
from workers.tasks.preannotate import MIN_LIFTED_KEYPOINTS
from workers.tasks.working_inputs import WorkingRig, lifted_at_full_resolution

TARGETS = {"found_and_fitted": 0.95, "epipolar_median_px": 5.0, "fit_residual_median_frac": 0.01,
           "scale_factor_rel_error": 0.20}


def _assemble(cameras: list[Camera], videos: Path, out: Path, every: int) -> Path:
    assemble_capture(cameras, out, videos=videos, every=every, name="handpose3d", workers=1, force=True)
    return out


def run(*, quick: bool = False, every: int | None = None, emit_json: bool = True) -> dict[str, Any]:
    """Run the benchmark; return its record (printed as the last stdout line when `emit_json`)."""
    status = detector_status()
    if status is not None:
        raise RuntimeError(f"bench realrig needs the detector: {status}")
    handpose3d_dir()  # RealDataMissingError (a FileNotFoundError) names where it looked
    every = every or (30 if quick else 5)
    started = time.perf_counter()
    load_before = os.getloadavg()
    settings = get_settings()
    with tempfile.TemporaryDirectory(prefix="handloop-realrig-") as tmp_name:
        tmp = Path(tmp_name)
        calibration_dir = write_handpose3d_opencv(tmp / "calibration")
        videos = link_handpose3d_videos(tmp / "videos")
        as_read = convert("opencv", calibration_dir, unit="m", unknown_scale=True)  # as a lab would: unit unknown
        wrong = _assemble(as_read.cameras, videos, tmp / "capture-as-read", every)
        report = check_capture(wrong, source="detector", max_frames=10 if quick else 40,
                               log=lambda line: print(line, file=sys.stderr))
        if report.hand_scale is None or not np.isfinite(report.hand_scale.factor):
            raise RuntimeError(f"the calibration check could not judge the scale: {report.summary} {report.notes}")
        factor = report.hand_scale.factor
        scaled = convert("opencv", calibration_dir, scale=factor)
        right = _assemble(scaled.cameras, videos, tmp / "capture", every)
        figures = _preannotate(right, settings)
        arrays = load_hand_model(settings.mano_path)
        reference = factor * _model_over_lifted_bones(arrays, figures.pop("lifted_keypoints"))
        record = {
            **figures,
            "scale_flagged": report.scale_wrong,
            "scale_message": report.hand_scale.message(),
            "scale_factor": round(factor, 5),
            "reference_factor": round(reference, 5),
            "scale_factor_rel_error": round(abs(factor - reference) / reference, 4),
            "rig_span_as_read_m": round(as_read.span_m, 3),
            "rig_span_scaled_m": round(scaled.span_m, 4),
            "check_pair_median_px": None if not report.pairs else report.pairs[0].median_px,
            "check_verdict": report.verdict,
            "targets": TARGETS,
        }
        record["targets_met"] = {
            "found_and_fitted": record["found_and_fitted"] >= TARGETS["found_and_fitted"],
            "epipolar_median_px": record["epipolar_median_px"] <= TARGETS["epipolar_median_px"],
            "fit_residual_median_frac": record["fit_residual_median_frac"] <= TARGETS["fit_residual_median_frac"],
            "scale_factor_rel_error": record["scale_factor_rel_error"] <= TARGETS["scale_factor_rel_error"],
        }
        record["load_average_1min"] = {"start": round(load_before[0], 2), "end": round(os.getloadavg()[0], 2)}
        bench_settings = {"quick": quick, "every": every, "recording": "handpose3d", "hand_model": arrays.name,
                          "working_width_px": read_capture(right).working_width_px,
                          "torch_threads": torch.get_num_threads()}
    if emit_json:
        return emit("realrig", record, bench_settings, started)
    return {**record, "settings": bench_settings}


def _preannotate(capture_dir: Path, settings: Any) -> dict[str, Any]:
    """Round 0 on every frame as the pre-annotation job makes it: detect on the working copies, keypoints back in
    full pixels, the detection record, the detector fit (no masks: no green screen) reweighted once."""
    capture = read_capture(capture_dir)
    full = list(capture.cameras)
    small = list(working_cameras(full, capture.working_width_px))
    wrig = WorkingRig(capture.working_width_px, tuple(full), tuple(small))
    side = capture.hand_model.side
    config = fit_config_from_settings(settings, DETECTOR_SOURCE, with_masks=False)
    engine = FittingEngine(load_hand_model(settings.mano_path, side), full, config)
    refs = [ref for seq in capture.sequences for ref in seq.frames]
    view_ids = list(range(len(full)))
    fitted, epipolar, residual_frac, residual_px, lifted_points, seconds = 0, [], [], [], [], []
    missed: list[dict[str, int]] = []  # frames not fitted: in how many views the hand was found
    for ref in tqdm(refs, unit="frame", desc="bench realrig, round 0", file=sys.stderr):
        t0 = time.perf_counter()
        images = load_working_images(ref.image_paths, full, small)
        lifted = lifted_at_full_resolution(detect_frame([images[c.name] for c in full], small, handedness=side), wrig)
        record = detection_record(lifted, view_ids)
        views = lifted.views
        if views[0] is not None and views[1] is not None:
            epipolar.append(symmetric_epipolar_distances(views[0].keypoints_px, views[1].keypoints_px, *full))
        if lifted_count(record) < MIN_LIFTED_KEYPOINTS:
            seconds.append(time.perf_counter() - t0)
            found = sum(v is not None for v in views)
            missed.append({"frame": ref.index, "views_with_hand": found,
                           "lifted": lifted_count(record)})
            continue
        lifted_points.append(lifted.points_world)
        fit = fit_reweighted(engine, [observations_from_detection(record, full, None)])[0]
        seconds.append(time.perf_counter() - t0)
        fitted += 1
        uv, _ = project_points(fit.keypoints, full)
        for c, (view, cam) in enumerate(zip(views, full, strict=True)):
            if view is None:
                continue
            use = used_detections(view.keypoints_px, view.scores, view.presence, lifted.inliers[:, c], cam.width,
                                  cam.height)
            err = np.linalg.norm(uv[c][use] - view.keypoints_px[use], axis=1)
            residual_px.append(err)
            residual_frac.append(err / cam.width)
    found = np.concatenate(epipolar) if epipolar else np.zeros(0)
    frac = np.concatenate(residual_frac) if residual_frac else np.zeros(0)
    px = np.concatenate(residual_px) if residual_px else np.zeros(0)
    return {
        "frames": len(refs),
        "fitted": fitted,
        "found_and_fitted": round(fitted / max(len(refs), 1), 4),
        "not_fitted": missed,
        "epipolar_median_px": round(float(np.median(found)), 3) if found.size else None,
        "epipolar_p90_px": round(float(np.percentile(found, 90)), 3) if found.size else None,
        "fit_residual_median_px": round(float(np.median(px)), 3) if px.size else None,
        "fit_residual_median_frac": round(float(np.median(frac)), 5) if frac.size else None,
        "s_per_frame": round(float(np.median(seconds)), 3) if seconds else None,
        "lifted_keypoints": np.stack(lifted_points) if lifted_points else np.zeros((0, 21, 3)),
    }


# Bones (parent, child) in FreiHAND order: each finger's chain from the wrist.
BONES = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 5), (5, 6), (6, 7), (7, 8), (0, 9), (9, 10), (10, 11), (11, 12),
         (0, 13), (13, 14), (14, 15), (15, 16), (0, 17), (17, 18), (18, 19), (19, 20)]


def _model_over_lifted_bones(arrays: Any, lifted: np.ndarray) -> float:
    """The median over bones of (the hand model's mean-shape bone length / the lifted hand's median over frames):
    the factor that would give the lifted hand the model's adult size. lifted: (N, 21, 3) in the scaled rig's metres."""
    with torch.no_grad():
        rest = HandLayer(arrays, dtype=torch.float64)(betas=torch.zeros(1, 10, dtype=torch.float64)).keypoints[0]
    rest = rest.numpy()
    parent, child = np.array(BONES).T
    model = np.linalg.norm(rest[child] - rest[parent], axis=1)
    observed = np.nanmedian(np.linalg.norm(lifted[:, child] - lifted[:, parent], axis=2), axis=0)
    ratio = model / observed
    return float(np.median(ratio[np.isfinite(ratio)]))
