"""What a fit derives from a frame's masks alone, whatever the hand's pose: per view the outside-distance field and
the mask's undistorted pixels (for the wrist cut). Prepared once where the same frame is fitted twice
(`workers.fitting.reweight.fit_reweighted`: a first fit and its continuation); measured, the second fit's masks
cost ~30 ms per 8-view frame at 640 px otherwise (docs/benchmarks.md, "### Round 0's fit and lift, faster").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.fitting.inputs import FrameObservations
from workers.fitting.masks import MaskPixels, mask_pixels, outside_distance_px
from workers.geometry.camera import Camera


@dataclass(frozen=True, eq=False)
class FrameMasks:
    """One frame's mask preparation.

    Attributes:
        masks: the observations' masks it was made from (a fit checks it is given the same object).
        outside_px: per view the (H, W) float32 distance to the nearest mask pixel on the canvas of the rig's largest
            view (pixels, 0 inside), or None for a view without a mask.
        pixels: per view the mask's undistorted pixels (`mask_pixels`) where the mask is cut at the wrist, else None.
    """

    masks: tuple[np.ndarray | None, ...] | None
    outside_px: tuple[np.ndarray | None, ...]
    pixels: tuple[MaskPixels | None, ...]


def prepare_frame_masks(obs: FrameObservations, cameras: list[Camera], canvas_hw: tuple[int, int],
                        cut_at_wrist: bool) -> FrameMasks:
    """The frame's `FrameMasks` for these cameras (calibration order); `cut_at_wrist`: the fit cuts this frame's masks
    at the wrist (its config cuts, and the masks hold the forearm), so their pixels are undistorted here too."""
    H, W = canvas_hw
    outside: list[np.ndarray | None] = []
    pixels: list[MaskPixels | None] = []
    for c, cam in enumerate(cameras):
        mask = None if obs.masks is None else obs.masks[c]
        if mask is None or not np.any(mask):
            outside.append(None)
            pixels.append(None)
            continue
        mask = np.asarray(mask, dtype=bool)
        canvas = np.zeros((H, W), dtype=bool)
        canvas[: cam.height, : cam.width] = mask
        outside.append(outside_distance_px(canvas))
        pixels.append(mask_pixels(mask, cam) if cut_at_wrist else None)
    return FrameMasks(obs.masks, tuple(outside), tuple(pixels))
