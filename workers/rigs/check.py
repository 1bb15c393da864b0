"""The calibration check: do the cameras agree about where 2D keypoints are? (`handloop calibration check`)

From 2D keypoints of the same hand seen by every camera (ground truth in synthetic captures, the
detector's keypoints otherwise; annotators' clicks take the same path through `check_keypoints`):
- per camera pair, the symmetric epipolar distance (pixels, after undistortion): how far each keypoint
  lies from the epipolar line of its partner in the other view;
- per camera, the leave-one-out reprojection error (pixels): the keypoint triangulated from the OTHER
  cameras, projected into this one, against its own 2D keypoint.
The verdict: a camera's epipolar figure is the median, over its partners, of the pairs' median distance,
so one bad partner is outvoted (a good camera has it in one of C - 1 pairs, a bad camera in all of
them). A camera well above the others' lower quartile (a swapped name, a stale or mis-converted
extrinsic) is flagged; with several bad cameras, the worst is set aside and the rest judged again
without it, until the remaining cameras agree. The leave-one-out figure (the median over pairs of other
cameras of each pair's median error) is reported beside it, in pixels of the camera's own image.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from workers.geometry.camera import Camera

FLAG_RATIO = 3.0  # flagged when the median error exceeds this multiple of the lower quartile over cameras
FLAG_FLOOR_FRACTION = 0.003  # ... and this fraction of the image width (4 px on a 1280 px camera)
FLAG_FLOOR_MIN_PX = 2.0
MIN_POINTS = 6  # keypoints a camera needs (each also seen by two other cameras) to be judged ...
MIN_PAIRS = 3  # ... and this many partner cameras,
MIN_PAIR_POINTS = 3  # each pair's figure from at least this many keypoints
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
    """One camera, pixels: the leave-one-out reprojection (the median over pairs of other cameras of each
    pair's median error), the median over its partners of their pairs' median epipolar distance (what the
    verdict is judged by), the keypoint observations used, the limit it was judged by, and the verdict."""

    name: str
    reprojection_px: float
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
        """Plain JSON types; figures that could not be computed (NaN) are None."""
        def clean(row: dict[str, Any]) -> dict[str, Any]:
            return {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in row.items()}

        return {"source": self.source, "frames": self.frames, "flagged": self.flagged,
                "cameras": [clean(asdict(c)) for c in self.cameras], "pairs": [clean(asdict(p)) for p in self.pairs],
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
    from workers.geometry.projection import undistort_pixels  # deferred: torch; the API imports this module

    C = len(cameras)
    if C < 3:
        raise CheckError(f"the check needs at least 3 cameras to tell which one disagrees, the rig has {C}")
    notes = list(notes or [])
    pair_d: dict[tuple[int, int], list[np.ndarray]] = {p: [] for p in combinations(range(C), 2)}
    # loo[c][(a, b)]: errors in camera c of the points pair (a, b) of other cameras triangulated
    loo: list[dict[tuple[int, int], list[np.ndarray]]] = [{p: [] for p in pair_d if c not in p} for c in range(C)]
    F = {(a, b): _fundamental(cameras[a], cameras[b]) for a, b in pair_d}
    P = np.stack([cam.P for cam in cameras])
    observed: list[np.ndarray] = []  # per frame (C, K) bool: the keypoints each camera has
    for kp, vis in zip(keypoints_px, visible, strict=True):
        kp = np.where(vis[..., None], np.asarray(kp, dtype=np.float64), np.nan)
        ok = np.isfinite(kp).all(axis=2)
        observed.append(ok)
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
        for a, b in pair_d:  # every pair triangulates what both see and predicts it in every other camera
            both = ok[a] & ok[b]
            if not both.any():
                continue
            rows = [ideal[v, both, i:i + 1] * P[v, 2] - P[v, i] for v in (a, b) for i in (0, 1)]
            Xh = np.linalg.svd(np.stack(rows, axis=1))[2][:, -1]
            X = Xh[:, :3] / Xh[:, 3:]
            for c in range(C):
                seen = ok[c, both]
                if c not in (a, b) and seen.any():
                    loo[c][(a, b)].append(np.linalg.norm(_pinhole(P[c], X[seen]) - ideal[c, both][seen], axis=1))
    pairs = [PairFigure(cameras[a].name, cameras[b].name, round(_stat(d, 0.5), 3), round(_stat(d, 0.9), 3),
                        int(sum(np.isfinite(x).sum() for x in d))) for (a, b), d in pair_d.items()]
    # Each pair of other cameras scores a camera by its median error over what the pair triangulated.
    pair_score = [{p: _stat(errs, 0.5) for p, errs in loo[c].items()
                   if sum(np.isfinite(e).sum() for e in errs) >= MIN_PAIR_POINTS} for c in range(C)]
    epipolar = {(a, b): f.median_px for (a, b), f in zip(pair_d, pairs, strict=True) if f.points >= MIN_PAIR_POINTS}
    floors = np.array([max(FLAG_FLOOR_MIN_PX, FLAG_FLOOR_FRACTION * cam.width) for cam in cameras])

    def judge(trusted: set[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int], float]:
        """With only trusted cameras judging: per camera the median epipolar distance to its trusted
        partners, whether it is judged, the leave-one-out figure, its observations, and the typical figure."""
        epi = np.array([float(np.median(v)) if (v := [d for p, d in epipolar.items() if c in p
                                                       and set(p) - {c} <= trusted]) else float("nan")
                        for c in range(C)])
        partners = [sum(1 for p in epipolar if c in p and set(p) - {c} <= trusted) for c in range(C)]
        scores = [[v for p, v in pair_score[c].items() if set(p) <= trusted] for c in range(C)]
        reproj = np.array([float(np.median(sc)) if sc else float("nan") for sc in scores])
        rows = sorted(trusted)
        counts = [int(sum((ok[c] & (ok[[o for o in rows if o != c]].sum(axis=0) >= 2)).sum() for ok in observed))
                  for c in range(C)]
        judged = np.array([partners[c] >= MIN_PAIRS and counts[c] >= MIN_POINTS for c in range(C)])
        among = [c for c in trusted if judged[c]]
        # the lower quartile: the good cameras' figure even when several cameras are bad
        typical = float(np.quantile(epi[among], 0.25)) if among else float("nan")
        return epi, judged, reproj, counts, typical

    # A camera's epipolar figure is the median over its partners, so a bad partner is outvoted; with
    # several bad cameras the worst is set aside and the others judged again without it, until the
    # remaining cameras agree.
    trusted = set(range(C))
    flagged: list[int] = []
    while True:
        epi, judged, reproj, counts, typical = judge(trusted)
        limits = np.maximum(floors, FLAG_RATIO * np.nan_to_num(typical))
        over = [c for c in trusted if judged[c] and epi[c] > limits[c]]
        if not over or len(trusted) <= 3:
            break
        worst = max(over, key=lambda c: epi[c] / limits[c])
        trusted.discard(worst)
        flagged.append(worst)
    figures = []
    for c, cam in enumerate(cameras):
        is_flagged = c in flagged or bool(judged[c] and epi[c] > limits[c])
        reason = ""
        if is_flagged:
            reason = (f"camera {cam.name!r}: its keypoints lie {epi[c]:.1f} px (median) from the epipolar lines of "
                      f"the other cameras' (typical {typical:.1f} px), and keypoints triangulated from the others "
                      f"land {reproj[c]:.1f} px from its own: its calibration disagrees with the others (stale or "
                      "mis-converted extrinsics, a swapped name, or wrong intrinsics)")
        elif not judged[c]:
            notes.append(f"camera {cam.name!r}: only {counts[c]} usable keypoints (seen by two other cameras too), "
                         f"not judged (needs {MIN_POINTS}, and {MIN_PAIRS} partners)")
        figures.append(CameraFigure(cam.name, round(float(reproj[c]), 3), round(float(epi[c]), 3), counts[c],
                                    round(float(limits[c]), 3), is_flagged, reason))
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
        from workers.detector import detector_status  # deferred: loads the detector's pipeline (torch)

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
    # deferred: the capture reader pulls in cv2 and PIL; the API imports this module for check_keypoints
    from workers.capture import load_frame_masks, load_ground_truth, read_capture
    from workers.capture.working import load_working_images, mask_to_working, to_full_px, working_cameras

    capture = read_capture(path, check_images=False)
    try:
        frames = _frames(capture, sequence_id, max_frames)
    except KeyError as exc:
        raise CheckError(str(exc.args[0])) from None
    cameras = list(capture.cameras)
    small = list(working_cameras(cameras, capture.working_width_px))
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
            from workers.detector import DetectorInputError, detect_frame  # deferred: the pipeline (torch)

            # The detector reads the images at the capture's working width; its keypoints come back in full pixels.
            images = load_working_images(frame.image_paths, cameras, small)
            masks = load_frame_masks(frame)
            try:
                lifted = detect_frame([images[c.name] for c in cameras], small,
                                      [mask_to_working(masks[c.name], s) if c.name in masks else None
                                       for c, s in zip(cameras, small, strict=True)] if masks else None,
                                      handedness=capture.hand_model.side)  # type: ignore[arg-type]
            except DetectorInputError as exc:
                notes.append(f"{frame.sequence_id} frame {frame.index}: skipped ({exc})")
                continue
            kp = np.full((len(cameras), 21, 2), np.nan)
            vis = np.zeros((len(cameras), 21), bool)
            for c, view in enumerate(lifted.views):
                if view is not None:
                    kp[c] = to_full_px(view.keypoints_px, small[c], cameras[c])
                    vis[c] = view.scores >= DETECTOR_MIN_SCORE
            keypoints.append(kp)
            visible.append(vis)
        if log and (n + 1) % 10 == 0:
            log(f"check: {n + 1}/{len(frames)} frames")
    return check_keypoints(cameras, keypoints, visible, source=source, notes=notes)


def format_report(report: CheckReport) -> str:
    """The report as text: one line per camera, then the pairs, then the verdict."""
    lines = [f"calibration check from {report.source} keypoints, {report.frames} frames", "",
             f"{'camera':<12} {'epipolar px':>12} {'limit px':>9} {'reproj px':>10} {'points':>7}  verdict"]
    for c in report.cameras:
        lines.append(f"{c.name:<12} {c.epipolar_px:>12.2f} {c.threshold_px:>9.2f} {c.reprojection_px:>10.2f} "
                     f"{c.points:>7d}  {'FLAGGED' if c.flagged else 'ok'}")
    lines += ["", "pairs (median / p90 epipolar distance, px):"]
    lines += [f"  {p.a}-{p.b}: {p.median_px:.2f} / {p.p90_px:.2f} ({p.points} points)" for p in report.pairs]
    lines += [""] + [c.reason for c in report.cameras if c.flagged] + [f"note: {n}" for n in report.notes]
    lines.append(f"flagged: {', '.join(report.flagged)}" if report.flagged else "no camera disagrees with the others")
    return "\n".join(lines)
