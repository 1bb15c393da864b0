"""The calibration check: do the cameras agree about where 2D keypoints are? (`handloop calibration check`)

From 2D keypoints of the same hand seen by every camera (ground truth in synthetic captures, the
detector's keypoints otherwise; annotators' clicks take the same path through `check_keypoints`):
- per camera pair, the symmetric epipolar distance (pixels, after undistortion): how far each keypoint
  lies from the epipolar line of its partner in the other view;
- per camera, the leave-one-out reprojection error (pixels): the keypoint triangulated from the OTHER
  cameras, projected into this one, against its own 2D keypoint.
A camera whose median leave-one-out error is well above the others' (a swapped name, a stale or
mis-converted extrinsic) is flagged. The prediction from the other cameras is the coordinate-wise median
over every pair of them, so one bad camera (in a minority of the pairs) does not drag the good ones
over the limit.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from workers.geometry.camera import Camera

FLAG_RATIO = 3.0  # flagged when the median error exceeds this multiple of the median over cameras
FLAG_FLOOR_FRACTION = 0.003  # ... and this fraction of the image width (4 px on a 1280 px camera)
FLAG_FLOOR_MIN_PX = 2.0
MIN_POINTS = 6  # keypoints a camera needs to be judged
DETECTOR_MIN_SCORE = 0.5


class CheckError(ValueError):
    """The check cannot run (no keypoints source, too few cameras); the message says why."""


@dataclass(frozen=True)
class PairFigure:
    """Epipolar agreement of two cameras: median and 90th percentile distance, pixels, over `points`."""

    a: str
    b: str
    median_px: float
    p90_px: float
    points: int


@dataclass(frozen=True)
class CameraFigure:
    """One camera: leave-one-out reprojection (median, 90th percentile, pixels), its pairs' median
    epipolar distance, the keypoints used, the threshold it was judged by, and the verdict."""

    name: str
    reprojection_px: float
    reprojection_p90_px: float
    epipolar_px: float
    points: int
    threshold_px: float
    flagged: bool
    reason: str = ""


@dataclass
class CheckReport:
    """The check's figures; `flagged` names the cameras that disagree with the others."""

    source: str
    frames: int
    cameras: list[CameraFigure]
    pairs: list[PairFigure]
    notes: list[str] = field(default_factory=list)

    @property
    def flagged(self) -> list[str]:
        return [c.name for c in self.cameras if c.flagged]

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "frames": self.frames, "flagged": self.flagged,
                "cameras": [asdict(c) for c in self.cameras], "pairs": [asdict(p) for p in self.pairs],
                "notes": list(self.notes)}


def _fundamental(a: Camera, b: Camera) -> np.ndarray:
    """(3, 3) F with x_b^T F x_a = 0 for undistorted pixels of cameras a and b."""
    R = b.R @ a.R.T
    t = b.t - R @ a.t
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(b.K).T @ tx @ R @ np.linalg.inv(a.K)


def _line_distance(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(N,) distance of xb (N, 2) to the epipolar lines F xa, pixels."""
    ha, hb = np.c_[xa, np.ones(len(xa))], np.c_[xb, np.ones(len(xb))]
    lines = ha @ F.T
    return np.abs(np.sum(lines * hb, axis=1)) / np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-12)


def _pinhole(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(N, 2) undistorted pixels of points X (N, 3) through one (3, 4) P; NaN behind the camera."""
    h = np.c_[X, np.ones(len(X))] @ P.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = h[:, :2] / h[:, 2:]
    uv[h[:, 2] <= 0] = np.nan
    return uv


def _predicted_pixels(ideal: np.ndarray, ok: np.ndarray, P: np.ndarray, P_target: np.ndarray) -> np.ndarray:
    """(N, 2) where the other views put each point in the target view: every pair of them triangulates it
    (two-view DLT), the pairs' projections into the target are combined by a coordinate-wise median, so
    one bad camera among the others (in a minority of pairs) does not move the prediction.

    Args:
        ideal: (V, N, 2) undistorted pixels of the other views; ok: (V, N) bool observed; P: (V, 3, 4);
        P_target: (3, 4) of the target camera. NaN where no pair saw the point.
    """
    V, N = ok.shape
    predictions = []
    for a, b in combinations(range(V), 2):
        both = ok[a] & ok[b]
        uv = np.full((N, 2), np.nan)
        if both.any():
            rows = [ideal[v, both, i:i + 1] * P[v, 2] - P[v, i] for v in (a, b) for i in (0, 1)]
            Xh = np.linalg.svd(np.stack(rows, axis=1))[2][:, -1]  # (n, 4)
            uv[both] = _pinhole(P_target, Xh[:, :3] / Xh[:, 3:])
        predictions.append(uv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: points no pair saw
        return np.nanmedian(np.stack(predictions), axis=0)


def _stat(values: list[np.ndarray], q: float) -> float:
    flat = np.concatenate(values) if values else np.zeros(0)
    flat = flat[np.isfinite(flat)]
    return float(np.quantile(flat, q)) if flat.size else float("nan")


def check_keypoints(cameras: list[Camera], keypoints_px: list[np.ndarray], visible: list[np.ndarray], *,
                    source: str = "keypoints", notes: list[str] | None = None) -> CheckReport:
    """The figures from per-frame 2D keypoints.

    Args:
        cameras: the C cameras of the calibration under test.
        keypoints_px: per frame (C, K, 2) distorted pixels (NaN where not seen).
        visible: per frame (C, K) bool, the keypoints to use.
        source: where the keypoints came from, for the report.
    Returns:
        The report; cameras with fewer than MIN_POINTS usable keypoints are not judged (noted).
    """
    from workers.geometry.projection import undistort_pixels

    C = len(cameras)
    if C < 3:
        raise CheckError(f"the check needs at least 3 cameras to tell which one disagrees, the rig has {C}")
    notes = list(notes or [])
    pair_d: dict[tuple[int, int], list[np.ndarray]] = {p: [] for p in combinations(range(C), 2)}
    loo: list[list[np.ndarray]] = [[] for _ in range(C)]
    F = {(a, b): _fundamental(cameras[a], cameras[b]) for a, b in pair_d}
    P = np.stack([cam.P for cam in cameras])
    for kp, vis in zip(keypoints_px, visible, strict=True):
        kp = np.where(vis[..., None], np.asarray(kp, dtype=np.float64), np.nan)
        ok = np.isfinite(kp).all(axis=2)
        ideal = np.full_like(kp, np.nan)
        for c, cam in enumerate(cameras):
            if ok[c].any():
                ideal[c, ok[c]] = undistort_pixels(kp[c, ok[c]], cam)
        for (a, b), F_ab in F.items():
            both = ok[a] & ok[b]
            if both.any():
                d1 = _line_distance(F_ab, ideal[a, both], ideal[b, both])
                d2 = _line_distance(F_ab.T, ideal[b, both], ideal[a, both])
                pair_d[(a, b)].append((d1 + d2) / 2)
        for c in range(C):
            others = np.array([o for o in range(C) if o != c])
            use = ok[c] & (ok[others].sum(axis=0) >= 2)
            if use.any():
                predicted = _predicted_pixels(ideal[others][:, use], ok[others][:, use], P[others], P[c])
                loo[c].append(np.linalg.norm(predicted - ideal[c, use], axis=1))
    pairs = [PairFigure(cameras[a].name, cameras[b].name, round(_stat(d, 0.5), 3), round(_stat(d, 0.9), 3),
                        int(sum(np.isfinite(x).sum() for x in d))) for (a, b), d in pair_d.items()]
    medians = np.array([_stat(loo[c], 0.5) for c in range(C)])
    judged = np.array([sum(np.isfinite(x).sum() for x in loo[c]) >= MIN_POINTS for c in range(C)])
    typical = float(np.nanmedian(medians[judged])) if judged.any() else float("nan")
    figures = []
    for c, cam in enumerate(cameras):
        count = int(sum(np.isfinite(x).sum() for x in loo[c]))
        threshold = max(FLAG_FLOOR_MIN_PX, FLAG_FLOOR_FRACTION * cam.width, FLAG_RATIO * typical)
        epi = [p.median_px for p in pairs if cam.name in (p.a, p.b) and np.isfinite(p.median_px)]
        flagged = bool(judged[c] and medians[c] > threshold)
        reason = ""
        if flagged:
            reason = (f"camera {cam.name!r}: keypoints triangulated from the other cameras land {medians[c]:.1f} px "
                      f"(median) from its own, against {typical:.1f} px typical: its calibration disagrees with the "
                      "others (stale or mis-converted extrinsics, a swapped name, or wrong intrinsics)")
        elif not judged[c]:
            notes.append(f"camera {cam.name!r}: only {count} usable keypoints, not judged (needs {MIN_POINTS})")
        figures.append(CameraFigure(cam.name, round(float(medians[c]), 3), round(_stat(loo[c], 0.9), 3),
                                    round(float(np.median(epi)), 3) if epi else float("nan"), count,
                                    round(threshold, 3), flagged, reason))
    return CheckReport(source=source, frames=len(keypoints_px), cameras=figures, pairs=pairs, notes=notes)


def _frames(capture: Any, sequence_id: str | None, max_frames: int) -> list[Any]:
    seqs = [capture.sequence(sequence_id)] if sequence_id else list(capture.sequences)
    frames = [f for s in seqs for f in s.frames]
    if len(frames) > max_frames:
        frames = [frames[i] for i in np.linspace(0, len(frames) - 1, max_frames).round().astype(int)]
    return frames


def detector_unavailable() -> str | None:
    """None when workers.detector can detect; else why not (module absent, or its own status)."""
    try:
        from workers.detector import detector_status

        return detector_status()
    except ImportError as exc:
        return f"the detector is not part of this build ({exc})"


def check_capture(path: Path, *, source: str = "auto", sequence_id: str | None = None, max_frames: int = 50,
                  log: Callable[[str], None] | None = None) -> CheckReport:
    """Run the check on a capture folder.

    Args:
        path: the capture.
        source: "ground-truth", "detector" or "auto" (ground truth when the capture has it, else the detector).
        sequence_id: only this sequence (default: all).
        max_frames: frames used, spread evenly.
        log: progress and fallback messages.
    Raises:
        CheckError: no usable keypoint source; CaptureError: the capture is malformed.
    """
    from workers.capture import load_frame_images, load_frame_masks, load_ground_truth, read_capture

    capture = read_capture(path, check_images=False)
    try:
        frames = _frames(capture, sequence_id, max_frames)
    except KeyError as exc:
        raise CheckError(str(exc.args[0])) from None
    cameras = list(capture.cameras)
    has_gt = bool(frames) and all(f.ground_truth_path is not None for f in frames)
    notes: list[str] = []
    if source == "auto":
        source = "ground-truth" if has_gt else "detector"
    if source == "ground-truth" and not has_gt:
        raise CheckError(f"{path}: the capture has no ground truth; use --keypoints detector")
    if source == "detector":
        why = detector_unavailable()
        if why is not None:
            raise CheckError(f"the detector cannot run: {why}. Without it the check needs 2D keypoints: ground truth "
                             "(synthetic captures) or annotators' clicks (after a round of annotation)")
    keypoints, visible = [], []
    for n, frame in enumerate(frames):
        if source == "ground-truth":
            gt = load_ground_truth(frame)
            keypoints.append(gt.keypoints_2d)
            visible.append(gt.visibility)
        else:
            from workers.detector import DetectorInputError, detect_frame

            images = load_frame_images(frame, cameras)
            masks = load_frame_masks(frame)
            try:
                lifted = detect_frame([images[c.name] for c in cameras], cameras,
                                      [masks.get(c.name) for c in cameras] if masks else None,
                                      handedness=capture.hand_model.side)  # type: ignore[arg-type]
            except DetectorInputError as exc:
                notes.append(f"{frame.sequence_id} frame {frame.index}: skipped ({exc})")
                continue
            kp = np.full((len(cameras), 21, 2), np.nan)
            vis = np.zeros((len(cameras), 21), bool)
            for c, view in enumerate(lifted.views):
                if view is not None:
                    kp[c] = view.keypoints_px
                    vis[c] = view.scores >= DETECTOR_MIN_SCORE
            keypoints.append(kp)
            visible.append(vis)
        if log and (n + 1) % 10 == 0:
            log(f"check: {n + 1}/{len(frames)} frames")
    return check_keypoints(cameras, keypoints, visible, source=source, notes=notes)


def format_report(report: CheckReport) -> str:
    """The report as text: one line per camera, then the pairs, then the verdict."""
    lines = [f"calibration check from {report.source} keypoints, {report.frames} frames", "",
             f"{'camera':<12} {'reproj med px':>13} {'p90 px':>8} {'epipolar px':>12} {'points':>7} "
             f"{'limit px':>9}  verdict"]
    for c in report.cameras:
        lines.append(f"{c.name:<12} {c.reprojection_px:>13.2f} {c.reprojection_p90_px:>8.2f} {c.epipolar_px:>12.2f} "
                     f"{c.points:>7d} {c.threshold_px:>9.2f}  {'FLAGGED' if c.flagged else 'ok'}")
    lines += ["", "pairs (median / p90 epipolar distance, px):"]
    lines += [f"  {p.a}-{p.b}: {p.median_px:.2f} / {p.p90_px:.2f} ({p.points} points)" for p in report.pairs]
    lines += [""] + [c.reason for c in report.cameras if c.flagged] + [f"note: {n}" for n in report.notes]
    lines.append(f"flagged: {', '.join(report.flagged)}" if report.flagged else "no camera disagrees with the others")
    return "\n".join(lines)
