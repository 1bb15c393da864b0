"""A per-keypoint correction of the detector's lifted keypoints toward the project's own keypoints, learned from
its labels.

Why: MediaPipe's landmarks follow MediaPipe's annotation convention, not the hand model's. On synthetic captures
of the built-in hand the lifted fingertips sit 6-13 mm short along their bone, the finger joints 2-12 mm, and the
thumb's base ~9 mm off (docs/benchmarks.md, "### Detector keypoint offsets"; an earlier study saw the same on two
seeds). A difference of convention is a constant in the right frame, so a few labels learn it (3 gave most of it).
The frame is the bone's leading into the keypoint (along the bone; the palm's normal made orthogonal to it; their
cross product): finger flexion turns an offset expressed in the palm's frame with the finger, and in that study a
palm frame made the fingertips worse. Each component is the median over the labelled frames, which the detector's
gross failures (a thumb > 30 mm off on ~8 % of keypoints) do not move. The palm's normal flips with handedness;
a round's frames are all of one hand (workers/tasks/training.ROUND_HANDEDNESS), so its offsets are consistent.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from workers.handmodel.keypoints import NUM_KEYPOINTS, SKELETON_EDGES

# Parent of each FreiHAND keypoint (the wrist's "bone" runs from the middle finger's MCP to the wrist).
MIDDLE_MCP = 9
PARENT: tuple[int, ...] = (MIDDLE_MCP, *(p for p, _ in SKELETON_EDGES))
WRIST, INDEX_MCP, PINKY_MCP = 0, 5, 17
# Fewer labelled frames than this leave a keypoint uncorrected. Measured (docs/benchmarks.md, "### Detector keypoint
# offsets"): offsets from 2 / 3 random labelled frames already take the lift's median on an unseen subject from 10.2 to
# 6.5 / 6.1 mm (worst of 30 draws 7.3 / 7.4); 3 keeps one frame's outlier from setting a median alone.
MIN_FRAMES = 3
# The pose term (below) is learned from this many fully lifted labelled frames, no fewer: from 13 it moved the largest
# keypoint error of held-out frames little, from 30 it took it from 31 to 20-23 mm (a study on seed 1515's capture,
# 2026-12-05, docs/benchmarks.md).
POSE_MIN_FRAMES = 30
# Ridge penalty on the standardised pose: 3-10 did best from 30 to 108 frames, 100 was worse (same study).
POSE_RIDGE = 10.0
# A pose's leverage h at which its pose-dependent correction is halved. 0.3-1 kept the gain on held-out frames of
# labelled sequences and the error on unlabelled subjects near the offsets' (two seeds), 0.5 in between (same study).
POSE_LEVERAGE_SCALE = 0.5
# Coordinates of the pose whose spread over the labelled frames is below this (metres) are constant by construction
# (the wrist is the palm frame's origin, the middle MCP lies on its first axis) and left out.
POSE_MIN_SPREAD_M = 1e-5


def palm_normal(points: np.ndarray) -> np.ndarray:
    """(..., 21, 3) keypoints -> (..., 3) the palm's normal (index MCP - wrist) x (pinky MCP - wrist), not unit."""
    wrist = points[..., WRIST, :]
    return np.cross(points[..., INDEX_MCP, :] - wrist, points[..., PINKY_MCP, :] - wrist)


def bone_frames(points_m: np.ndarray) -> np.ndarray:
    """Per keypoint an orthonormal frame attached to the bone leading into it.

    Args:
        points_m: (..., 21, 3) keypoints, metres, any frame (world).
    Returns:
        (..., 21, 3, 3) rotations whose columns are the frame's axes in the input frame: (1) parent -> keypoint,
        (2) the palm's normal (index MCP - wrist) x (pinky MCP - wrist) made orthogonal to (1), (3) = (1) x (2).
        NaN where a point it needs is missing or the bone has no length.
    """
    p = np.asarray(points_m, dtype=np.float64)
    if p.shape[-2:] != (NUM_KEYPOINTS, 3):
        raise ValueError(f"points must be (..., {NUM_KEYPOINTS}, 3), got {p.shape}")
    with np.errstate(invalid="ignore", divide="ignore"):
        along = p - p[..., PARENT, :]
        along = along / np.linalg.norm(along, axis=-1, keepdims=True)
        normal = np.broadcast_to(palm_normal(p)[..., None, :], along.shape)
        side = normal - (normal * along).sum(-1, keepdims=True) * along
        side = side / np.linalg.norm(side, axis=-1, keepdims=True)
        third = np.cross(along, side)
    frames = np.stack([along, side, third], axis=-1)
    frames[~np.isfinite(frames).all(axis=(-2, -1))] = np.nan
    return frames


def palm_frame(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The hand's own frame: origin at the wrist, axes (1) wrist -> middle MCP, (2) the palm's normal
    (index MCP - wrist) x (pinky MCP - wrist) made orthogonal to (1), (3) = (2) x (1).

    Args:
        points_m: (..., 21, 3) keypoints, metres, any frame (world).
    Returns:
        origin (..., 3) metres and rotation (..., 3, 3) whose columns are the axes in the input frame; NaN where a
        point it needs is missing or degenerate.
    """
    p = np.asarray(points_m, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        origin = p[..., WRIST, :]
        first = p[..., MIDDLE_MCP, :] - origin
        first = first / np.linalg.norm(first, axis=-1, keepdims=True)
        normal = palm_normal(p)
        normal = normal - (normal * first).sum(-1, keepdims=True) * first
        normal = normal / np.linalg.norm(normal, axis=-1, keepdims=True)
        rotation = np.stack([first, normal, np.cross(normal, first)], axis=-1)
    return origin, rotation


@dataclass(frozen=True)
class PoseCorrection:
    """A correction of the keypoints that depends on the hand's pose, learned by ridge regression from the labels.

    Why: the constant offsets correct the detector's convention, not its pose-dependent errors (its thumb, > 30 mm
    off on some poses, is most of the largest keypoint errors the heuristic's max 3D distance rejects). Seen from the
    hand's own frame those errors follow the lifted pose: on held-out frames of labelled sequences a linear map from
    the pose to the correction took the median largest keypoint error of a frame from 31-37 to 15-20 mm with 108
    labelled frames (docs/benchmarks.md, "### A pose-dependent correction of the detector's keypoints"). A pose
    unlike the labelled ones (another subject's hand) gets less of it: the pose-dependent part is scaled by
    1 / (1 + h / POSE_LEVERAGE_SCALE), h the pose's ridge leverage. Without that, on subjects without a label the
    median keypoint error rose (5.3 -> 7.1 mm); with it, it stays within 0.6 mm of the offsets' or improves.

    Attributes:
        mean: (63,) the labelled frames' mean pose, metres, palm frame (the 21 keypoints after the offsets, flattened).
        weights: (63, 63) pose (minus mean) -> correction, both flattened (21, 3) in the palm frame.
        bias: (63,) the correction at the mean pose, metres.
        leverage: (63, 63) h = (pose - mean) @ leverage @ (pose - mean), 1 / m^2: the ridge's leverage of a pose.
        frames_used: the labelled frames it was learned from.
    """

    mean: np.ndarray
    weights: np.ndarray
    bias: np.ndarray
    leverage: np.ndarray
    frames_used: int

    def apply(self, points_m: np.ndarray) -> np.ndarray:
        """points (..., 21, 3) metres -> (..., 21, 3) corrected; a frame whose palm frame is undefined stays as it
        is, and so does a keypoint that is missing (a missing one's coordinates read as the mean pose's)."""
        p = np.asarray(points_m, dtype=np.float64)
        origin, rotation = palm_frame(p)
        local = np.einsum("...ji,...kj->...ki", rotation, p - origin[..., None, :])
        flat = local.reshape(*local.shape[:-2], 3 * NUM_KEYPOINTS)
        flat = np.where(np.isfinite(flat), flat, self.mean)
        centred = flat - self.mean
        h = np.einsum("...i,ij,...j->...", centred, self.leverage, centred)
        delta = ((centred @ self.weights) / (1 + h / POSE_LEVERAGE_SCALE)[..., None] + self.bias).reshape(local.shape)
        shift = np.einsum("...ij,...kj->...ki", rotation, delta)
        return np.where(np.isfinite(shift) & np.isfinite(p), p + shift, p)


def fit_pose_correction(points_m: np.ndarray, labels_m: np.ndarray, ridge: float = POSE_RIDGE,
                        min_frames: int = POSE_MIN_FRAMES) -> PoseCorrection | None:
    """Learn a PoseCorrection from N frames' keypoints (after the offsets) and labels, (N, 21, 3) metres world;
    frames with a missing keypoint are left out. None where fewer than `min_frames` remain."""
    points = np.asarray(points_m, dtype=np.float64)
    labels = np.asarray(labels_m, dtype=np.float64)
    if points.ndim != 3 or points.shape != labels.shape or points.shape[1:] != (NUM_KEYPOINTS, 3):
        raise ValueError(f"points and labels must both be (N, {NUM_KEYPOINTS}, 3), got {points.shape} and "
                         f"{labels.shape}")
    origin, rotation = palm_frame(points)
    local = np.einsum("nji,nkj->nki", rotation, points - origin[:, None])
    target = np.einsum("nji,nkj->nki", rotation, labels - origin[:, None]) - local
    x = local.reshape(len(local), -1)
    y = target.reshape(len(target), -1)
    usable = np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1)
    if usable.sum() < min_frames:
        return None
    x, y = x[usable], y[usable]
    mean, spread = x.mean(axis=0), x.std(axis=0)
    varies = spread > POSE_MIN_SPREAD_M
    xs = (x[:, varies] - mean[varies]) / spread[varies]  # standardised, so one penalty fits every coordinate
    bias = y.mean(axis=0)
    inverse = np.linalg.inv(xs.T @ xs + ridge * np.eye(xs.shape[1]))
    weights = np.zeros((x.shape[1], y.shape[1]))
    weights[varies] = inverse @ xs.T @ (y - bias) / spread[varies, None]
    leverage = np.zeros((x.shape[1], x.shape[1]))
    leverage[np.ix_(varies, varies)] = inverse / np.outer(spread[varies], spread[varies])
    return PoseCorrection(mean, weights, bias, leverage, int(usable.sum()))


@dataclass(frozen=True)
class KeypointOffsets:
    """Learned offsets of the detector's keypoints.

    Attributes:
        offsets_m: (21, 3) float64 per keypoint, metres, in its bone frame (bone_frames); 0 where not learned.
        frames_used: (21,) int the labelled frames each keypoint's median came from (0: not learned).
        pose: the pose-dependent correction applied after the offsets, or None (not asked for, or too few labels).
    """

    offsets_m: np.ndarray
    frames_used: np.ndarray
    pose: PoseCorrection | None = None

    @classmethod
    def none(cls) -> KeypointOffsets:
        """No correction."""
        return cls(np.zeros((NUM_KEYPOINTS, 3)), np.zeros(NUM_KEYPOINTS, dtype=np.int64))

    def summary(self) -> dict[str, list[float] | list[int] | int]:
        """For a checkpoint's metadata: per keypoint the offset along its bone and its length (mm; positive along
        the bone: the label lies farther along it than the detection) and the labelled frames it came from; the
        frames the pose term was learned from (0: none)."""
        return {"along_bone_mm": [round(1000 * float(v), 2) for v in self.offsets_m[:, 0]],
                "length_mm": [round(1000 * float(v), 2) for v in np.linalg.norm(self.offsets_m, axis=1)],
                "samples": [int(n) for n in self.frames_used],
                "pose_frames": self.pose.frames_used if self.pose is not None else 0}

    def apply(self, points_m: np.ndarray) -> np.ndarray:
        """Corrected keypoints: points (..., 21, 3) metres -> (..., 21, 3), each moved by its offset in the frame
        of the uncorrected points; a keypoint whose frame is undefined (a point it needs is NaN) stays as it is."""
        p = np.asarray(points_m, dtype=np.float64)
        shift = np.einsum("...kij,kj->...ki", bone_frames(p), self.offsets_m)
        moved = np.where(np.isfinite(shift), p + shift, p)
        return self.pose.apply(moved) if self.pose is not None else moved


def fit_keypoint_offsets(lifted_m: np.ndarray, labels_m: np.ndarray, min_frames: int = MIN_FRAMES, *,
                         pose: bool = False) -> KeypointOffsets:
    """Learn the offsets from N frames with both the detector's lifted keypoints and a label.

    Args:
        lifted_m: (N, 21, 3) the detector's lifted keypoints, metres, world frame; NaN rows where not lifted.
        labels_m: (N, 21, 3) the labels' keypoints (the fitted hand model's), metres, world frame.
        min_frames: a keypoint with fewer usable frames keeps a zero offset.
        pose: also learn the pose-dependent correction (fit_pose_correction) of the offset-corrected keypoints.
    Returns:
        KeypointOffsets: per keypoint and axis the median of (label - lifted) in the lifted bone frame.
    """
    lifted = np.asarray(lifted_m, dtype=np.float64)
    labels = np.asarray(labels_m, dtype=np.float64)
    if lifted.ndim != 3 or lifted.shape != labels.shape or lifted.shape[1:] != (NUM_KEYPOINTS, 3):
        raise ValueError(f"lifted and labels must both be (N, {NUM_KEYPOINTS}, 3), got {lifted.shape} and "
                         f"{labels.shape}")
    if not np.isfinite(labels).all():
        raise ValueError("labels must be finite")
    local = np.einsum("nkji,nkj->nki", bone_frames(lifted), labels - lifted)  # R^T (label - lifted)
    usable = np.isfinite(local).all(axis=-1)
    offsets = np.zeros((NUM_KEYPOINTS, 3))
    used = usable.sum(axis=0)
    for k in np.flatnonzero(used >= min_frames):
        offsets[k] = np.median(local[usable[:, k], k], axis=0)
    constant = KeypointOffsets(offsets, np.where(used >= min_frames, used, 0).astype(np.int64))
    if not pose:
        return constant
    return replace(constant, pose=fit_pose_correction(constant.apply(lifted), labels))
