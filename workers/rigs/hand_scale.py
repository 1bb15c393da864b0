"""Is a rig's length unit right? Judge it by the size of the hand it triangulates.

A calibration in the wrong unit (board squares read as metres, centimetres as metres) triangulates a hand that is
many times too large or too small, while every pixel-based check still passes. The 20 bones between the 21
keypoints are compared with an adult hand's: the factor that makes the hand adult-sized is the median over bones
of each bone's median over frames of reference / measured length (robust to a bone the detector misplaces and to
frames with a wrong match). Keypoints are triangulated with the rig as it is (plain DLT in the calibration's own
unit, workers.geometry.triangulation), so no metric threshold decides which points survive.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.triangulation import triangulate
from workers.handmodel.keypoints import KEYPOINT_NAMES, NUM_KEYPOINTS, SKELETON_EDGES

# Per SKELETON_EDGES bone (parent -> child, FreiHAND order), metres: the built-in hand at rest (workers/handmodel,
# hand length 188 mm wrist to middle tip, between ANSUR II's women's 181 and men's 193 mm means; a test checks these
# against the model). Wrist -> MCP bones include the carpus; DIP -> tip the distal phalanx and its pad.
REFERENCE_BONE_M: dict[str, float] = {
    "thumb_mcp": 0.0250, "thumb_pip": 0.0477, "thumb_dip": 0.0372, "thumb_tip": 0.0300,
    "index_mcp": 0.0882, "index_pip": 0.0466, "index_dip": 0.0272, "index_tip": 0.0183,
    "middle_mcp": 0.0847, "middle_pip": 0.0505, "middle_dip": 0.0323, "middle_tip": 0.0204,
    "ring_mcp": 0.0801, "ring_pip": 0.0464, "ring_dip": 0.0313, "ring_tip": 0.0201,
    "pinky_mcp": 0.0796, "pinky_pip": 0.0388, "pinky_dip": 0.0222, "pinky_tip": 0.0176,
}  # fmt: skip
REFERENCE_HAND_LENGTH_M = 0.188
# Adult hands (ANSUR II 5th..95th percentiles, women and men): 165..210 mm wrist crease to middle tip.
ADULT_HAND_LENGTH_M = (0.165, 0.210)
# The factor range called plausible: wider than adult hands, for children's and large hands and detector noise
# (a hand 125..280 mm long). A wrong unit is off by 2.5x (inches), 10x, 100x or more.
PLAUSIBLE_FACTOR = (REFERENCE_HAND_LENGTH_M / 0.280, REFERENCE_HAND_LENGTH_M / 0.125)
MIN_BONES = 5  # bones measured in at least one frame, for a verdict
# Keypoints whose bones disagree more than this (interquartile range of the per-bone factors over their median) are
# no hand's: detector hands measured 0.14-0.39 a frame (0.24 over 12 frames of the real recording), random 21-point
# clouds 0.61-1.8. No verdict on the scale is given from them.
MAX_SPREAD = 0.55


@dataclass(frozen=True)
class HandScale:
    """The hand-size verdict on a rig's scale.

    Attributes:
        factor: multiply the calibration's lengths by this to make the hand adult-sized (NaN: too few bones).
        hand_length: the hand's wrist -> middle fingertip length in the points' unit (REFERENCE_HAND_LENGTH_M /
            factor; NaN when unknown).
        verdict: "plausible", "too large", "too small" or "unknown" (fewer than MIN_BONES bones measured, or bones
            that disagree more than MAX_SPREAD: not a hand's proportions).
        bones: bones measured in at least one frame.
        frames: frames with at least one bone measured.
        spread: the per-bone factors' interquartile range over their median (0 for a perfectly proportioned hand).
    """

    factor: float
    hand_length: float
    verdict: str
    bones: int
    frames: int
    spread: float

    @property
    def plausible(self) -> bool:
        return self.verdict == "plausible"

    def message(self, unit: str = "m") -> str:
        """One sentence for people; `unit` names the points' length unit ("m" for handloop cameras)."""
        if self.verdict == "unknown" and self.bones >= MIN_BONES:
            return (f"the hand's size cannot be judged: its bones disagree (spread {self.spread:.2f}, a hand's is at "
                    f"most {MAX_SPREAD}): the keypoints do not have a hand's proportions")
        if self.verdict == "unknown":
            return (f"the hand's size cannot be judged: {self.bones} of {len(SKELETON_EDGES)} bones measured "
                    f"(at least {MIN_BONES} needed)")
        lo, hi = ADULT_HAND_LENGTH_M
        size = (f"the triangulated hand measures {self.hand_length:.4g} {unit} from wrist to middle fingertip "
                f"(median of {self.bones} bones over {self.frames} frame(s); adult hands {lo}..{hi} m)")
        if self.plausible:
            return f"{size}: the calibration's scale looks right (factor {self.factor:.3g})"
        times = 1.0 / self.factor if self.verdict == "too large" else self.factor
        return (f"{size}: the calibration's scale looks wrong, the hand is {self.verdict} by {times:.3g}x; "
                f"reconvert it with handloop calibration convert --scale set to {self.factor:.4g} times the metres "
                f"per file unit it was read with (a file read in metres: --scale {self.factor:.4g}; a file in "
                "calibration-board squares: the square's size in metres)")


def bone_lengths(points_3d: np.ndarray) -> np.ndarray:
    """(N, 21, 3) keypoints (NaN where missing) -> (N, 20) bone lengths in SKELETON_EDGES order (NaN where either
    end is missing)."""
    points = np.asarray(points_3d, dtype=np.float64)
    if points.ndim != 3 or points.shape[1:] != (NUM_KEYPOINTS, 3):
        raise ValueError(f"points_3d must have shape (N, {NUM_KEYPOINTS}, 3), got {points.shape}")
    parents, children = (np.array(ix) for ix in zip(*SKELETON_EDGES, strict=True))
    return np.linalg.norm(points[:, children] - points[:, parents], axis=-1)


def estimate_hand_scale(points_3d: np.ndarray) -> HandScale:
    """The factor that makes the hand of `points_3d` adult-sized, and the verdict on it.

    Args:
        points_3d: (N, 21, 3) FreiHAND-order keypoints of one hand over N frames, in the calibration's length unit
            (any world frame), NaN where missing.
    Returns:
        HandScale; verdict "too large" when the hand is bigger than any adult's (factor < PLAUSIBLE_FACTOR[0]),
        "too small" when smaller (factor > PLAUSIBLE_FACTOR[1]).
    """
    lengths = bone_lengths(points_3d)
    reference = np.array([REFERENCE_BONE_M[KEYPOINT_NAMES[child]] for _, child in SKELETON_EDGES])
    usable = np.isfinite(lengths) & (lengths > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_ratio = np.where(usable, np.log(reference[None] / np.where(usable, lengths, 1.0)), np.nan)
    measured = usable.any(axis=0)
    frames = int(usable.any(axis=1).sum())
    bones = int(measured.sum())
    if bones < MIN_BONES:
        return HandScale(math.nan, math.nan, "unknown", bones, frames, math.nan)
    per_bone = np.nanmedian(log_ratio[:, measured], axis=0)
    factor = float(np.exp(np.median(per_bone)))
    q1, q3 = np.exp(np.percentile(per_bone, [25, 75]))
    spread = float((q3 - q1) / factor)
    verdict = ("unknown" if spread > MAX_SPREAD else "too large" if factor < PLAUSIBLE_FACTOR[0]
               else "too small" if factor > PLAUSIBLE_FACTOR[1] else "plausible")
    return HandScale(factor, REFERENCE_HAND_LENGTH_M / factor, verdict, bones, frames, spread)


def triangulate_keypoints(pixels: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """Plain multi-view DLT of 2D hand keypoints, in the cameras' own length unit (no metric threshold).

    Args:
        pixels: (C, N, 21, 2) distorted pixels per camera and frame, NaN where not detected.
        cameras: the C cameras (translations in any length unit).
    Returns:
        (N, 21, 3) world points in the cameras' unit, NaN where fewer than two views saw the keypoint.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    C = len(cameras)
    if pixels.ndim != 4 or pixels.shape[0] != C or pixels.shape[2:] != (NUM_KEYPOINTS, 2):
        raise ValueError(f"pixels must have shape (C={C}, N, {NUM_KEYPOINTS}, 2), got {pixels.shape}")
    n = pixels.shape[1]
    # The pixel outlier threshold only matters with 3+ views; it is unit-free.
    tri = triangulate(pixels.reshape(C, n * NUM_KEYPOINTS, 2), cameras, outlier_px=20.0)
    return tri.points_world.reshape(n, NUM_KEYPOINTS, 3)


def hand_scale_of_views(keypoints_px: Sequence[np.ndarray | None], cameras: Sequence[Camera]) -> HandScale:
    """The hand-size verdict of one frame's detections: per camera (21, 2) distorted pixels or None (no hand),
    triangulated by `triangulate_keypoints`."""
    if len(keypoints_px) != len(cameras):
        raise ValueError(f"{len(keypoints_px)} views for {len(cameras)} cameras")
    pixels = np.stack([np.full((NUM_KEYPOINTS, 2), np.nan) if kp is None else np.asarray(kp, dtype=np.float64)
                       for kp in keypoints_px])[:, None]
    return estimate_hand_scale(triangulate_keypoints(pixels, list(cameras)))
