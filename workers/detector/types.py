"""What the detector hands to the rest of handloop: plain arrays and small records, no database, no web.

Conventions (docs/conventions.md): pixels with (0, 0) at the centre of the top-left pixel; the world frame in metres;
keypoints in FreiHAND order (0 wrist, 1-4 thumb, 5-8 index, 9-12 middle, 13-16 ring, 17-20 pinky).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Handedness = Literal["right", "left"]


class DetectorUnavailableError(RuntimeError):
    """The pretrained model files or their runtime are missing or corrupt; the message says what and how to install."""


class DetectorInputError(ValueError):
    """Input the detector cannot work with (no calibration, one view, an unreadable image, a box outside it)."""


@dataclass(frozen=True, eq=False)
class ViewKeypoints:
    """One view's 2D hand keypoints.

    Attributes:
        keypoints_px: (21, 2) float64, pixels of the full view.
        scores: (21,) float64 in [0, 1], per-keypoint confidence.
        presence: the model's hand-presence score in [0, 1] for the crop it kept.
        handedness: the side the keypoints were read as (the side asked for: a left hand is shown mirrored).
        box_px: (4,) float64 x, y, width, height of the crop's axis-aligned bounds in pixels.
        rotation_rad: rotation of the crop the model saw (counter-clockwise in the image, radians).
        right_score: the model's own handedness in [0, 1], high for a right hand (its handedness output on the
            unmirrored crop averaged with one minus it on the mirrored crop); NaN where not known.
    """

    keypoints_px: np.ndarray
    scores: np.ndarray
    presence: float
    handedness: Handedness
    box_px: np.ndarray
    rotation_rad: float
    right_score: float = field(default=math.nan)

    @property
    def model_side(self) -> Handedness | None:
        """The side the model thinks this hand is (None where its handedness is not known)."""
        if not math.isfinite(self.right_score):
            return None
        return "right" if self.right_score >= 0.5 else "left"


@dataclass(frozen=True, eq=False)
class LiftedKeypoints:
    """21 keypoints triangulated from the views of one frame.

    Attributes:
        points_world: (21, 3) float64 metres, world frame; NaN rows where fewer than two views agree.
        confidence: (21,) float64 in [0, 1], from view agreement, reprojection residual and scores (NaN where no point).
        inliers: (21, C) bool, the views each keypoint was triangulated from.
        reprojection_px: (21,) float64, median reprojection error over the inliers in pixels (NaN where no point).
        views: C entries in calibration order: the view's detection, or None where no hand was found.
    """

    points_world: np.ndarray
    confidence: np.ndarray
    inliers: np.ndarray
    reprojection_px: np.ndarray
    views: tuple[ViewKeypoints | None, ...]

    @property
    def frame_confidence(self) -> float:
        """One figure for the frame (mean keypoint confidence, 0 when nothing was lifted): the stand-in for MVNet's."""
        finite = np.isfinite(self.confidence)
        return float(self.confidence[finite].mean()) if finite.any() else 0.0
