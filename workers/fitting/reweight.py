"""Reweighting 2D keypoints by a first fit's residuals, for fits from a detector's keypoints.

A detector's keypoint that lies far from where a hand fitted to all views and keypoints puts it is likely wrong in
that view (a finger mistaken for another, a joint convention the hand model does not share): a Cauchy weight
1 / (1 + (r / s)^2) on its residual r lowers its pull in a second fit, with s a fraction of the hand's size in that
view. Measured on held-out frames (docs/benchmarks.md, "Round 0"): 7.46 -> 7.21 mm median vertex error at 640 px.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from workers.fitting.inputs import FrameObservations
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points

# The Cauchy scale as a fraction of the fitted hand's keypoint box in each view (0.05: ~4 px for a hand of 80 px).
RESIDUAL_SCALE_FRACTION = 0.05


def residual_reweighted(observations: FrameObservations, keypoints_world: np.ndarray, cameras: list[Camera],
                        scale_fraction: float = RESIDUAL_SCALE_FRACTION) -> FrameObservations:
    """The observations with each 2D keypoint's weight times 1 / (1 + (r / s)^2).

    Args:
        observations: C views' 2D keypoints (clicks_px (C, 21, 2) pixels, click_weights (C, 21)).
        keypoints_world: (21, 3) metres, world frame: the first fit's keypoints.
        cameras: the C cameras, calibration order.
        scale_fraction: s over the longer side of the fitted keypoints' box in the view (pixels / pixels).
    Returns:
        A copy with click_weights reweighted (points without a residual, NaN, keep weight 0); nothing else changes.
    """
    if not 0 < scale_fraction <= 1:
        raise ValueError(f"scale_fraction must be in (0, 1], not {scale_fraction}")
    pixels, _ = project_points(np.asarray(keypoints_world, dtype=np.float64), list(cameras))  # (C, 21, 2)
    residual = np.linalg.norm(pixels - observations.clicks_px, axis=2)  # (C, 21)
    hand_px = np.ptp(pixels, axis=1).max(axis=1, keepdims=True)  # (C, 1)
    scale = np.maximum(scale_fraction * hand_px, 1e-6)
    factor = np.where(np.isfinite(residual), 1.0 / (1.0 + (residual / scale) ** 2), 0.0)
    return replace(observations, click_weights=observations.click_weights * factor)
