"""Benchmark of the fitting engine (`handloop bench fit`) on synthetic frames with ground truth.

Clicks: wrist + five fingertips in every view where visible, with Gaussian click noise sigma in
{0, 2, 5} px; masks: the ground-truth hand masks or the capture's chroma-key masks (hand, forearm,
sleeve and held object); fitted with and without the silhouette term. Every frame is fitted alone for
the seconds-per-frame figures; the main configuration is also fitted as one batch for throughput.
The capture uses a seed the tests do not use.
"""

from __future__ import annotations

import logging
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
from backend.settings import get_settings
from workers.capture import load_frame_masks, load_ground_truth, read_capture
from workers.fitting.config import FitConfig
from workers.fitting.engine import FittingEngine
from workers.fitting.inputs import FrameObservations
from workers.handmodel.keypoints import SPARSE_KEYPOINTS
from workers.handmodel.loading import load_hand_model
from workers.synth.generator import generate_capture
from workers.synth.plan import SynthConfig

log = logging.getLogger(__name__)

BENCH_SEED = 9001
SIGMAS_PX = (0.0, 2.0, 5.0)


def simulated_clicks(keypoints_2d: np.ndarray, visibility: np.ndarray, sizes: list[tuple[int, int]],
                     sigma_px: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Clicks of a careful annotator on the sparse keypoints: (C, 21, 2) pixels and (C, 21) weights.

    keypoints_2d (C, 21, 2), visibility (C, 21); sizes per view (width, height). Clicks land inside
    the image; hidden keypoints get no click.
    """

    clicks = np.full(keypoints_2d.shape, np.nan)
    weights = np.zeros(visibility.shape)
    for c, (width, height) in enumerate(sizes):
        for k in SPARSE_KEYPOINTS:
            if not visibility[c, k]:
                continue
            xy = keypoints_2d[c, k] + rng.normal(0.0, sigma_px, 2)
            clicks[c, k] = np.clip(xy, 0, [width - 1, height - 1])
            weights[c, k] = 1.0
    return clicks, weights


def _load_frames(capture_dir: Path) -> tuple[list[dict[str, Any]], list]:
    capture = read_capture(capture_dir)
    frames = []
    for sequence in capture.sequences:
        if not sequence.green_screen:
            continue  # chroma-key masks exist on green-screen sequences only
        for ref in sequence.frames:
            gt = load_ground_truth(ref)
            chroma = load_frame_masks(ref)
            frames.append({"gt": gt, "chroma": tuple(chroma[c.name] for c in capture.cameras),
                           "hand": tuple(gt.hand_masks[c.name] for c in capture.cameras)})
    return frames, list(capture.cameras)


def run(*, quick: bool = False, emit_json: bool = True, frames_per_sequence: int | None = None) -> dict[str, Any]:
    """Run the benchmark; return its record (printed as the last stdout line when `emit_json`).

    Frames: 3 green-screen sequences of `frames_per_sequence` frames (default 10, i.e. 30 frames;
    3 with `quick`).
    """
    if frames_per_sequence is not None and frames_per_sequence < 1:
        raise ValueError(f"frames_per_sequence must be >= 1, got {frames_per_sequence}")


    started = time.perf_counter()
    load_before = os.getloadavg()
    settings = get_settings()
    per_sequence = frames_per_sequence or (3 if quick else 10)
    synth = SynthConfig(num_sequences=4, frames_per_sequence=per_sequence, seed=BENCH_SEED,
                        width_px=settings.render_width_px)
    with tempfile.TemporaryDirectory(prefix="handloop-bench-fit-") as tmp:
        log.info("rendering a %d-sequence synthetic capture (seed %d)", synth.num_sequences, BENCH_SEED)
        generate_capture(Path(tmp) / "capture", synth, mano_path=settings.mano_path)
        frames, cameras = _load_frames(Path(tmp) / "capture")
    arrays = load_hand_model(settings.mano_path)
    sizes = [(c.width, c.height) for c in cameras]
    rows: list[dict[str, Any]] = []
    combos = [(s, m, sil) for s in SIGMAS_PX for m in ("ground_truth", "chroma_key") for sil in (True, False)]
    engines = {sil: FittingEngine(arrays, cameras, FitConfig(use_silhouette=sil)) for sil in (True, False)}
    main_observations: list[FrameObservations] = []
    with tqdm(total=len(combos) * len(frames), unit="fit", desc="bench fit", file=sys.stderr) as bar:
        for sigma, mask_kind, silhouette in combos:
            rng = np.random.default_rng(BENCH_SEED + int(10 * sigma))
            vertex_mm, keypoint_mm, seconds, cpu_seconds, iterations = [], [], [], [], []
            for frame in frames:
                gt = frame["gt"]
                clicks, weights = simulated_clicks(gt.keypoints_2d, gt.visibility, sizes, sigma, rng)
                hand_only = mask_kind == "ground_truth"
                masks = frame["hand"] if hand_only else frame["chroma"]
                obs = FrameObservations(clicks, weights, masks, masks_include_forearm=not hand_only)
                if (sigma, mask_kind, silhouette) == (2.0, "chroma_key", True):
                    main_observations.append(obs)
                t0, c0 = time.perf_counter(), time.process_time()
                result = engines[silhouette].fit([obs])[0]
                seconds.append(time.perf_counter() - t0)
                # CPU time too: on a shared machine wall time also counts other people's work.
                cpu_seconds.append(time.process_time() - c0)
                iterations.append(result.diagnostics.iterations)
                vertex_mm.append(1000 * np.linalg.norm(result.vertices - gt.vertices, axis=1).mean())
                keypoint_mm.append(1000 * np.linalg.norm(result.keypoints - gt.keypoints_3d, axis=1).mean())
                bar.update()
            rows.append({
                "sigma_px": sigma, "masks": mask_kind, "silhouette": silhouette, "frames": len(frames),
                "vertex_mm": round(float(np.mean(vertex_mm)), 3),
                "vertex_mm_median": round(float(np.median(vertex_mm)), 3),
                "keypoint_mm": round(float(np.mean(keypoint_mm)), 3),
                "median_s_per_frame": round(float(np.median(seconds)), 4),
                "p90_s_per_frame": round(float(np.percentile(seconds, 90)), 4),
                "median_cpu_s_per_frame": round(float(np.median(cpu_seconds)), 4),
                "mean_iterations": round(float(np.mean(iterations)), 1),
            })
            log.info("sigma %.0f px, %s masks, silhouette %s: vertex %.2f mm, keypoints %.2f mm, median %.2f s",
                     sigma, mask_kind, silhouette, rows[-1]["vertex_mm"], rows[-1]["keypoint_mm"],
                     rows[-1]["median_s_per_frame"])
    t0 = time.perf_counter()
    engines[True].fit(main_observations)
    batched_fps = len(main_observations) / (time.perf_counter() - t0)
    load_after = os.getloadavg()

    def pick(sigma: float, masks: str, silhouette: bool) -> dict[str, Any]:
        return next(r for r in rows if (r["sigma_px"], r["masks"], r["silhouette"]) == (sigma, masks, silhouette))

    main = pick(2.0, "chroma_key", True)
    all_seconds = [r["median_s_per_frame"] for r in rows]
    record = {
        "median_s_per_frame": main["median_s_per_frame"],
        "p90_s_per_frame": main["p90_s_per_frame"],
        "median_cpu_s_per_frame": main["median_cpu_s_per_frame"],
        "median_s_per_frame_all_rows": round(float(np.median(all_seconds)), 4),
        "frames_per_s_batched": round(batched_fps, 3),
        "vertex_mm_exact": pick(0.0, "ground_truth", True)["vertex_mm"],
        "vertex_mm_exact_no_silhouette": pick(0.0, "ground_truth", False)["vertex_mm"],
        "vertex_mm_noisy": main["vertex_mm"],
        "vertex_mm_noisy_no_silhouette": pick(2.0, "chroma_key", False)["vertex_mm"],
        "keypoint_mm_noisy": main["keypoint_mm"],
        "load_average_1min": {"start": round(load_before[0], 2), "end": round(load_after[0], 2)},
        "rows": rows,
    }
    config = FitConfig()
    bench_settings = {
        "quick": quick, "frames": len(frames), "capture_seed": BENCH_SEED, "width_px": synth.width_px,
        "hand_model": arrays.name, "torch_threads": torch.get_num_threads(),
        "optimizer": config.optimizer,
        "max_iterations": config.global_iterations + config.full_iterations,
        "weights": vars(config.weights),
    }
    if emit_json:
        return emit("fit", record, bench_settings, started)
    return {**record, "settings": bench_settings}
