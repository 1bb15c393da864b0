"""Per-keypoint robust triangulation of the views' detections, and a confidence per keypoint.

RANSAC over views (every pair's DLT is a hypothesis, exhaustive for <= 8 views: 28 pairs), reprojection inliers, then
Gauss-Newton refinement over the inliers (workers/geometry/triangulation.py). The outlier threshold scales with the
hand's size in pixels, since the detector's error does (about 6 % of the hand box at 320 and 640 px).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from workers.detector.types import LiftedKeypoints, ViewKeypoints
from workers.geometry.camera import Camera
from workers.geometry.triangulation import triangulate

NUM_KEYPOINTS = 21
# Reprojection inlier threshold as a fraction of the median hand size (longer side of the keypoints' box) over views.
OUTLIER_FRACTION = 0.12
MIN_OUTLIER_PX = 3.0
# No keypoint of a human hand lies farther than this from the median of its keypoints (mid-palm; a long adult hand's
# middle fingertip is ~12 cm from it). Two nearly parallel rays that agree by chance triangulate metres away.
HAND_RADIUS_M = 0.15


def keypoint_confidence(inlier_count: np.ndarray, residual_px: np.ndarray, mean_score: np.ndarray,
                        outlier_px: float) -> np.ndarray:
    """(N,) confidence in [0, 1] = mean inlier score x support x fit.

    support = 1 - 0.5 ** (inliers - 1) (two views 0.5, three 0.75, four 0.875: agreement of more views counts more);
    fit = exp(-(residual / outlier_px) ** 2), residual the median reprojection error over the inliers.
    """
    support = 1.0 - 0.5 ** np.maximum(inlier_count - 1, 0)
    fit = np.exp(-((residual_px / outlier_px) ** 2))
    return np.clip(mean_score * support * fit, 0.0, 1.0)


def lift(views: Sequence[ViewKeypoints | None], cameras: Sequence[Camera]) -> LiftedKeypoints:
    """Triangulate 21 keypoints from C views (None where no hand was found) into the world frame (metres).

    A keypoint farther than HAND_RADIUS_M from the median of the lifted keypoints is not lifted (NaN, no inliers).
    """
    C = len(cameras)
    pixels = np.full((C, NUM_KEYPOINTS, 2), np.nan)
    weights = np.zeros((C, NUM_KEYPOINTS))
    sizes = []
    for c, view in enumerate(views):
        if view is None:
            continue
        pixels[c] = view.keypoints_px
        # A keypoint scored 0 would drop out entirely; a floor keeps it as a weak vote the RANSAC may still use.
        weights[c] = np.maximum(view.scores, 1e-3)
        sizes.append(float(np.ptp(view.keypoints_px, axis=0).max()))
    points = np.full((NUM_KEYPOINTS, 3), np.nan)
    confidence = np.full(NUM_KEYPOINTS, np.nan)
    inliers = np.zeros((NUM_KEYPOINTS, C), dtype=bool)
    residual = np.full(NUM_KEYPOINTS, np.nan)
    if len(sizes) >= 2:
        outlier_px = max(MIN_OUTLIER_PX, OUTLIER_FRACTION * float(np.median(sizes)))
        tri = triangulate(pixels, list(cameras), weights, outlier_px=outlier_px, refine=True)
        valid = tri.valid.copy()
        if valid.sum() >= 3:
            center = np.median(tri.points_world[valid], axis=0)
            valid &= np.linalg.norm(tri.points_world - center, axis=1) <= HAND_RADIUS_M
        points[valid] = tri.points_world[valid]
        inliers = tri.inliers.T & valid[:, None]
        residual[valid] = tri.median_reprojection_px[valid]
        count = inliers.sum(axis=1)
        mean_score = np.where(inliers, weights.T, 0).sum(axis=1) / np.maximum(count, 1)
        conf = keypoint_confidence(count, np.nan_to_num(residual, nan=np.inf), mean_score, outlier_px)
        confidence[valid] = conf[valid]
    return LiftedKeypoints(points, confidence, inliers, residual, tuple(views))
