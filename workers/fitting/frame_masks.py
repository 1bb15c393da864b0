"""What a fit derives from its frames' masks alone, whatever the hand's pose: per view the outside-distance field
and the mask's undistorted pixels (for the wrist cut). Prepared once where the same frames are fitted twice
(`workers.fitting.reweight.fit_reweighted`: a first fit and its continuation); measured, the second fit's masks cost
~30 ms per 8-view frame at 640 px otherwise (docs/benchmarks.md, "### Round 0's fit and lift, faster").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.fitting.inputs import FrameObservations
from workers.fitting.masks import MaskPixels, mask_pixels, outside_distance_px
from workers.geometry.camera import Camera


@dataclass(frozen=True, eq=False)
class PreparedMasks:
    """The mask preparation of B frames seen by C cameras.

    Attributes:
        masks: per frame the observations' masks it was made from (a fit checks it is given the same objects).
        outside_px: (B, C, H, W) float32 distance to the nearest mask pixel, pixels (0 inside), on a canvas of the
            rig's largest view (H, W); 0 for a view without a mask. One array, as the fit uses it: sharing it adds
            no copy.
        has_mask: (B, C) bool, the views with a (non-empty) mask.
        pixels: per frame and view the mask's undistorted pixels (`mask_pixels`) where the mask is cut at the
            wrist, else None.
    """

    masks: tuple[tuple[np.ndarray | None, ...] | None, ...]
    outside_px: np.ndarray
    has_mask: np.ndarray
    pixels: tuple[tuple[MaskPixels | None, ...], ...]

    def matches(self, frames: list[FrameObservations]) -> bool:
        """Whether this was prepared from these frames' masks (the same objects, in order)."""
        return len(frames) == len(self.masks) and all(f.masks is m for f, m in zip(frames, self.masks, strict=True))


def prepare_masks(frames: list[FrameObservations], cameras: list[Camera], cut_at_wrist: bool) -> PreparedMasks:
    """The frames' `PreparedMasks` for these cameras (calibration order); `cut_at_wrist`: the fit cuts masks that hold
    the forearm at the wrist (`FrameObservations.masks_include_forearm`), so their pixels are undistorted here too."""
    H = max(c.height for c in cameras)
    W = max(c.width for c in cameras)
    outside = np.zeros((len(frames), len(cameras), H, W), dtype=np.float32)
    has_mask = np.zeros((len(frames), len(cameras)), dtype=bool)
    pixels: list[tuple[MaskPixels | None, ...]] = []
    for b, obs in enumerate(frames):
        row: list[MaskPixels | None] = []
        for c, cam in enumerate(cameras):
            mask = None if obs.masks is None else obs.masks[c]
            if mask is None or not np.any(mask):
                row.append(None)
                continue
            mask = np.asarray(mask, dtype=bool)
            canvas = np.zeros((H, W), dtype=bool)
            canvas[: cam.height, : cam.width] = mask
            outside[b, c] = outside_distance_px(canvas)
            has_mask[b, c] = True
            row.append(mask_pixels(mask, cam) if cut_at_wrist and obs.masks_include_forearm else None)
        pixels.append(tuple(row))
    return PreparedMasks(tuple(f.masks for f in frames), outside, has_mask, tuple(pixels))
