"""Hand localisation: a hand box per view from a mask (chroma key or HandSegNet), and the 3D hand centre by
triangulating the box centres (the paper used a hand detector plus triangulation).

A view whose mask has no hand blob (or whose box disagrees with the others) is left out; with fewer than
two usable views the frame cannot be localised (`LocalisationError`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.triangulation import triangulate


class LocalisationError(ValueError):
    """The hand could not be localised (fewer than two views show it)."""


@dataclass(frozen=True)
class HandLocation:
    """Where the hand is in one frame.

    Attributes:
        center_world: (3,) metres, world frame, the triangulated box centre.
        boxes_px: (C, 4) x0, y0, x1, y1 per view, pixels (inclusive pixel centres); NaN without a hand.
        views_used: (C,) bool, views whose box centre was an inlier of the triangulation.
        reprojection_px: mean reprojection error of the box centres over the used views, pixels.
    """

    center_world: np.ndarray
    boxes_px: np.ndarray
    views_used: np.ndarray
    reprojection_px: float


def mask_box(mask: np.ndarray, min_area_px: int = 12) -> np.ndarray:
    """(H, W) bool mask -> (4,) x0, y0, x1, y1 of its largest connected blob, or NaN when none is large
    enough."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be (H, W), got {mask.shape}")
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if count <= 1:
        return np.full(4, np.nan)
    areas = stats[1:, cv2.CC_STAT_AREA]
    best = 1 + int(np.argmax(areas))
    if areas[best - 1] < min_area_px:
        return np.full(4, np.nan)
    x, y, w, h = (int(stats[best, k]) for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH,
                                                 cv2.CC_STAT_HEIGHT))
    return np.array([x, y, x + w - 1, y + h - 1], dtype=np.float64)


def localise_hand(masks: Sequence[np.ndarray] | np.ndarray, cameras: Sequence[Camera], *,
                  min_area_px: int = 12, outlier_px: float | None = None) -> HandLocation:
    """Triangulate the hand centre from per-view masks.

    Args:
        masks: C masks (H_c, W_c) bool (or probabilities > 0.5), in camera order.
        cameras: the C cameras.
        min_area_px: smaller blobs are ignored.
        outlier_px: reprojection error above which a view's box centre is an outlier (default: 6 % of
            the image width).
    Returns:
        HandLocation.
    Raises:
        LocalisationError: fewer than two views show the hand consistently.
        ValueError: masks and cameras disagree in number or size.
    """
    if len(masks) != len(cameras):
        raise ValueError(f"got {len(masks)} masks for {len(cameras)} cameras")
    boxes = np.full((len(cameras), 4), np.nan)
    for c, (mask, cam) in enumerate(zip(masks, cameras, strict=True)):
        mask = np.asarray(mask)
        if mask.shape != (cam.height, cam.width):
            raise ValueError(f"mask of {cam.name} is {mask.shape}, expected ({cam.height}, {cam.width})")
        boxes[c] = mask_box(mask > 0.5 if mask.dtype != bool else mask, min_area_px)
    centers = np.stack([(boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2], axis=1)  # (C, 2)
    if np.isfinite(centers).all(axis=1).sum() < 2:
        raise LocalisationError(f"the hand is visible in {int(np.isfinite(centers).all(axis=1).sum())} view(s); "
                                "triangulation needs at least two")
    tol = outlier_px if outlier_px is not None else 0.06 * float(np.mean([c.width for c in cameras]))
    result = triangulate(centers[:, None, :], list(cameras), outlier_px=tol)
    if not result.valid[0] or result.inliers[:, 0].sum() < 2:
        raise LocalisationError("the views' hand boxes do not agree on a 3D position")
    return HandLocation(center_world=result.points_world[0], boxes_px=boxes, views_used=result.inliers[:, 0],
                        reprojection_px=float(result.reprojection_px[0]))
