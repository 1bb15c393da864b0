"""Which of a view's stored detections a fit from the detector uses: one rule for the fit's input
(workers.tasks.detection_inputs) and for the review page that measures the fit against them
(backend.services.display.detection_points)."""

from __future__ import annotations

import numpy as np


def used_detections(keypoints_px: np.ndarray, scores: np.ndarray, presence: float, inliers: np.ndarray,
                    width: int, height: int) -> np.ndarray:
    """(21,) bool: keypoints whose detection the fit uses in this view.

    Args:
        keypoints_px: (21, 2) pixels, (0, 0) the centre of the top-left pixel; NaN where not detected.
        scores: (21,) the detector's per-keypoint scores (NaN read as 0).
        presence: the view's hand presence score.
        inliers: (21,) bool, True where this view is an inlier of the keypoint's triangulation.
        width, height: the view's size in pixels.
    Returns:
        True where the view is an inlier, the point lies inside the image ([-0.5, W - 0.5] x [-0.5, H - 0.5]) and
        both its score and the view's presence are positive.
    """
    xy = np.asarray(keypoints_px, dtype=np.float64)
    inside = (np.isfinite(xy).all(1) & (xy[:, 0] >= -0.5) & (xy[:, 0] <= width - 0.5)
              & (xy[:, 1] >= -0.5) & (xy[:, 1] <= height - 0.5))
    return np.asarray(inliers, dtype=bool) & inside & (np.nan_to_num(scores, nan=0.0) > 0) & (presence > 0)
