"""Hand localisation: a hand blob per view from a mask (chroma key or HandSegNet), and the 3D hand centre by
triangulating the blob centroids (the paper used a hand detector plus triangulation of box centres).

Each view offers its few largest blobs as candidates; the 3D centre is the two-view hypothesis that the
most views agree with (one candidate per view within the reprojection tolerance), re-solved over those
views. A false blob (a skin-coloured patch of the background, a view without the hand) is thereby left
out: backgrounds differ per view, so their blobs do not triangulate consistently. With fewer than two
consistent views the frame cannot be localised (`LocalisationError`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

import cv2
import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import project_points, undistort_pixels


class LocalisationError(ValueError):
    """The hand could not be localised (fewer than two views show it)."""


@dataclass(frozen=True)
class HandLocation:
    """Where the hand is in one frame.

    Attributes:
        center_world: (3,) metres, world frame, the triangulated blob centroids.
        boxes_px: (C, 4) x0, y0, x1, y1 per view, pixels (inclusive pixel centres); NaN without a hand.
        views_used: (C,) bool, views whose blob centroid was an inlier of the triangulation.
        reprojection_px: mean reprojection error of the centroids over the used views, pixels.
    """

    center_world: np.ndarray
    boxes_px: np.ndarray
    views_used: np.ndarray
    reprojection_px: float


def mask_blobs(mask: np.ndarray, min_area_px: int = 12, max_blobs: int = 3
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(H, W) bool mask -> boxes (n, 4) x0, y0, x1, y1, centroids (n, 2) (u, v) and areas (n,) of its up to
    `max_blobs` largest connected blobs (8-connected) of at least `min_area_px` pixels, largest first."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be (H, W), got {mask.shape}")
    _, _, stats, centroids = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = [i for i in np.argsort(-areas, kind="stable")[:max_blobs] if areas[i] >= min_area_px]
    boxes = np.array([[stats[1 + i, cv2.CC_STAT_LEFT], stats[1 + i, cv2.CC_STAT_TOP],
                       stats[1 + i, cv2.CC_STAT_LEFT] + stats[1 + i, cv2.CC_STAT_WIDTH] - 1,
                       stats[1 + i, cv2.CC_STAT_TOP] + stats[1 + i, cv2.CC_STAT_HEIGHT] - 1] for i in order],
                     dtype=np.float64).reshape(-1, 4)
    return boxes, centroids[[1 + i for i in order]].reshape(-1, 2), areas[order].astype(np.float64)


def mask_box(mask: np.ndarray, min_area_px: int = 12) -> np.ndarray:
    """(H, W) bool mask -> (4,) x0, y0, x1, y1 of its largest connected blob, or NaN when none is large
    enough."""
    boxes, _, _ = mask_blobs(mask, min_area_px, 1)
    return boxes[0] if len(boxes) else np.full(4, np.nan)


def _dlt(P: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Projection matrices (..., V, 3, 4), undistorted pixels (..., V, 2) -> (..., 3) points (row-normalised
    DLT, batched over the leading dimensions)."""
    rows = np.concatenate([uv[..., 0:1] * P[..., 2, :] - P[..., 0, :], uv[..., 1:2] * P[..., 2, :] - P[..., 1, :]],
                          axis=-2)  # (..., 2V, 4)
    rows = rows / (np.linalg.norm(rows[..., :3], axis=-1, keepdims=True) + 1e-12)
    X = np.linalg.svd(rows)[2][..., -1, :]
    return X[..., :3] / X[..., 3:4]


def localise_hand(masks: Sequence[np.ndarray] | np.ndarray, cameras: Sequence[Camera], *,
                  min_area_px: int = 12, outlier_px: float | None = None, max_blobs: int = 3) -> HandLocation:
    """Triangulate the hand centre from per-view masks.

    Args:
        masks: C masks (H_c, W_c) bool (or probabilities > 0.5), in camera order.
        cameras: the C cameras.
        min_area_px: smaller blobs are ignored.
        outlier_px: reprojection error above which a view's box centre is an outlier (default: 6 % of
            the image width).
        max_blobs: candidate blobs per view (the largest ones).
    Returns:
        HandLocation (boxes_px: the box of each view's chosen blob; NaN for views without a blob).
    Raises:
        LocalisationError: fewer than two views show the hand consistently.
        ValueError: masks and cameras disagree in number or size.
    """
    if len(masks) != len(cameras):
        raise ValueError(f"got {len(masks)} masks for {len(cameras)} cameras")
    C = len(cameras)
    candidates: list[tuple[np.ndarray, np.ndarray]] = []
    for mask, cam in zip(masks, cameras, strict=True):
        mask = np.asarray(mask)
        if mask.shape != (cam.height, cam.width):
            raise ValueError(f"mask of {cam.name} is {mask.shape}, expected ({cam.height}, {cam.width})")
        candidates.append(mask_blobs(mask > 0.5 if mask.dtype != bool else mask, min_area_px, max_blobs))
    seen = [c for c in range(C) if len(candidates[c][0])]
    if len(seen) < 2:
        raise LocalisationError(f"the hand is visible in {len(seen)} view(s); triangulation needs at least two")
    tol = outlier_px if outlier_px is not None else 0.06 * float(np.mean([c.width for c in cameras]))
    # Blob centroids, not box centres: a box centre moves by half a finger when a fingertip is missed.
    centers = [centroids for _, centroids, _ in candidates]
    ideal = [undistort_pixels(centers[c], cameras[c]) if len(centers[c]) else centers[c] for c in range(C)]
    P = np.stack([cam.P for cam in cameras])
    # Two-view hypotheses from every pair of candidates in every pair of views.
    pairs = [(c1, i, c2, j) for c1, c2 in combinations(seen, 2) for i in range(len(centers[c1]))
             for j in range(len(centers[c2]))]
    hyp = _dlt(np.stack([P[[c1, c2]] for c1, _, c2, _ in pairs]),
               np.stack([np.stack([ideal[c1][i], ideal[c2][j]]) for c1, i, c2, j in pairs]))  # (H, 3)
    projected, depth = project_points(hyp, list(cameras))  # (C, H, 2), (C, H)
    best_key, best = None, None
    for h in range(len(hyp)):
        if not np.isfinite(hyp[h]).all():
            continue
        chosen = np.full(C, -1)
        err = np.full(C, np.inf)
        for c in seen:
            if depth[c, h] <= 0:
                continue
            d = np.linalg.norm(centers[c] - projected[c, h], axis=1)
            k = int(np.argmin(d))
            if d[k] < tol:
                chosen[c], err[c] = k, d[k]
        inl = chosen >= 0
        area = sum(candidates[c][2][chosen[c]] for c in np.flatnonzero(inl))
        key = (int(inl.sum()), area, -float(np.mean(err[inl])) if inl.any() else 0.0)
        if best_key is None or key > best_key:
            best_key, best = key, chosen
    if best is None or (best >= 0).sum() < 2:
        raise LocalisationError("the views' hand boxes do not agree on a 3D position")
    used = best >= 0
    views = np.flatnonzero(used)
    X = _dlt(P[views], np.stack([ideal[c][best[c]] for c in views]))
    reproj, _ = project_points(X[None], [cameras[c] for c in views])
    error = float(np.mean([np.linalg.norm(reproj[k, 0] - centers[c][best[c]]) for k, c in enumerate(views)]))
    boxes = np.full((C, 4), np.nan)
    for c in seen:
        pick = best[c] if best[c] >= 0 else 0
        boxes[c] = candidates[c][0][pick]
    return HandLocation(center_world=X, boxes_px=boxes, views_used=used, reprojection_px=error)
