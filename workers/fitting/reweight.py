"""Reweighting 2D keypoints by a first fit's residuals, for fits from a detector's keypoints.

A detector's keypoint that lies far from where a hand fitted to all views and keypoints puts it is likely wrong in
that view (a finger mistaken for another, a joint convention the hand model does not share): a Cauchy weight
1 / (1 + (r / s)^2) on its residual r lowers its pull in a second fit, with s a fraction of the hand's size in that
view. Measured on held-out frames (docs/benchmarks.md, "Round 0"): 7.46 -> 7.21 mm median vertex error at 640 px, with
the keypoints weighed like clicks.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from workers.fitting.inputs import FrameObservations
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points

if TYPE_CHECKING:  # the engine imports torch; this module's reweighting is numpy only
    from workers.fitting.engine import FittingEngine
    from workers.fitting.result import FitResult

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


# The first fit's share of fit_reweighted's time (measured: 0.28 s and 0.14 s per frame at 640 px).
FIRST_FIT_SHARE = 0.67


def fit_reweighted(engine: FittingEngine, frames: list[FrameObservations],
                   progress: Callable[[float, str], None] | None = None) -> list[FitResult]:
    """Round 0's fit from a detector's keypoints, as the fit jobs and `handloop bench detect` both make it: a first
    fit, then the first continued (`FittingEngine.refine`: its second stage from the first's parameters) with each
    2D keypoint reweighted by its residual to the first (`residual_reweighted`).

    Where masks lead the fit (`LossWeights.detector_with_silhouettes`) one fit measured the same on held-out frames
    for half the CPU, but the loop's D_0 labels came out 0.3 mm worse and fewer fits passed the heuristic
    (docs/benchmarks.md, "### Round 0's fit once, tried"), so every detector frame is fitted twice. The second fit
    continues the first instead of starting again from the placements: on the 392 frames of the simulation's
    capture it was as good or better (green screen: 4.99 against 5.18 mm median vertex error, 75.9 against 73.4 %
    under 8 mm) for half its CPU (docs/benchmarks.md, "### Round 0's second fit continues the first").

    Args:
        engine: the fitting engine (its cameras are the frames' rig, calibration order).
        frames: each frame's observations (2D keypoints in pixels, masks, lifted 3D keypoints in metres, world frame).
        progress: called with (fraction in [0, 1], message) over both fits.
    Returns:
        The second fits, one per frame, in order; their diagnostics' iterations and seconds are both fits'.
    """
    def part(offset: float, share: float) -> Callable[[float, str], None] | None:
        return None if progress is None else (lambda f, m: progress(offset + share * f, m))

    cameras = list(engine.cameras)
    prepared = engine.prepare_masks(frames)  # the reweighted frames keep their masks: both fits share these
    first = engine.fit(frames, progress=part(0.0, FIRST_FIT_SHARE), prepared=prepared)
    second = [residual_reweighted(obs, result.keypoints, cameras) for obs, result in zip(frames, first, strict=True)]
    refined = engine.refine(second, first, progress=part(FIRST_FIT_SHARE, 1.0 - FIRST_FIT_SHARE), prepared=prepared)
    # The diagnostics count the work of both fits (solver steps, seconds per frame).
    out = []
    for a, b in zip(first, refined, strict=True):
        both = replace(b.diagnostics, iterations=a.diagnostics.iterations + b.diagnostics.iterations,
                       seconds=a.diagnostics.seconds + b.diagnostics.seconds)
        out.append(replace(b, diagnostics=both))
    return out
