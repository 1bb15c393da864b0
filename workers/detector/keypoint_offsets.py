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

from dataclasses import dataclass

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
        normal = np.cross(p[..., INDEX_MCP, :] - p[..., WRIST, :], p[..., PINKY_MCP, :] - p[..., WRIST, :])
        normal = np.broadcast_to(normal[..., None, :], along.shape)
        side = normal - (normal * along).sum(-1, keepdims=True) * along
        side = side / np.linalg.norm(side, axis=-1, keepdims=True)
        third = np.cross(along, side)
    frames = np.stack([along, side, third], axis=-1)
    frames[~np.isfinite(frames).all(axis=(-2, -1))] = np.nan
    return frames


@dataclass(frozen=True)
class KeypointOffsets:
    """Learned offsets of the detector's keypoints.

    Attributes:
        offsets_m: (21, 3) float64 per keypoint, metres, in its bone frame (bone_frames); 0 where not learned.
        frames_used: (21,) int the labelled frames each keypoint's median came from (0: not learned).
    """

    offsets_m: np.ndarray
    frames_used: np.ndarray

    @classmethod
    def none(cls) -> KeypointOffsets:
        """No correction."""
        return cls(np.zeros((NUM_KEYPOINTS, 3)), np.zeros(NUM_KEYPOINTS, dtype=np.int64))

    def summary(self) -> dict[str, list[float] | list[int]]:
        """For a checkpoint's metadata: per keypoint the offset along its bone and its length (mm; positive along
        the bone: the label lies farther along it than the detection) and the labelled frames it came from."""
        return {"along_bone_mm": [round(1000 * float(v), 2) for v in self.offsets_m[:, 0]],
                "length_mm": [round(1000 * float(v), 2) for v in np.linalg.norm(self.offsets_m, axis=1)],
                "samples": [int(n) for n in self.frames_used]}

    def apply(self, points_m: np.ndarray) -> np.ndarray:
        """Corrected keypoints: points (..., 21, 3) metres -> (..., 21, 3), each moved by its offset in the frame
        of the uncorrected points; a keypoint whose frame is undefined (a point it needs is NaN) stays as it is."""
        p = np.asarray(points_m, dtype=np.float64)
        shift = np.einsum("...kij,kj->...ki", bone_frames(p), self.offsets_m)
        return np.where(np.isfinite(shift), p + shift, p)


def fit_keypoint_offsets(lifted_m: np.ndarray, labels_m: np.ndarray, min_frames: int = MIN_FRAMES) -> KeypointOffsets:
    """Learn the offsets from N frames with both the detector's lifted keypoints and a label.

    Args:
        lifted_m: (N, 21, 3) the detector's lifted keypoints, metres, world frame; NaN rows where not lifted.
        labels_m: (N, 21, 3) the labels' keypoints (the fitted hand model's), metres, world frame.
        min_frames: a keypoint with fewer usable frames keeps a zero offset.
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
    return KeypointOffsets(offsets, np.where(used >= min_frames, used, 0).astype(np.int64))
