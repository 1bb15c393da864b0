"""The detector's 2D keypoints a pre-annotation fit (source "detector") was made from, read back from the
fit's inputs (`inputs["detection"]`, workers.tasks.detection_inputs.detection_record), for the review page to
measure the fit against them as it measures a fit from clicks against the clicks.

The rule is the fit input's (`workers.detector.usable.used_detections`, shared with
`observations_from_detection`): per view and keypoint the view's own detection where that view is an inlier of
the keypoint's triangulation, inside the image, with a positive score and presence.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from backend.services.display.view_geometry import ViewCamera
from workers.detector.usable import used_detections

logger = logging.getLogger(__name__)

NUM_KEYPOINTS = 21
SOURCE = "detector"  # the fit source (workers.tasks.detection_inputs.SOURCE)


def fitted_detections(inputs: dict[str, Any] | None, cameras: Sequence[ViewCamera]
                      ) -> dict[int, dict[int, tuple[float, float]]] | None:
    """view id -> keypoint -> (x, y) pixels: the detections the fit used. None for fits of any other source or
    an unreadable record (logged); {} when it used none."""
    inputs = inputs or {}
    record = inputs.get("detection") if inputs.get("source") == SOURCE else None
    if not isinstance(record, dict):
        return None
    try:
        view_ids = [int(v) for v in record["view_ids"]]
        inliers = np.asarray(record["inliers"], dtype=bool).reshape(NUM_KEYPOINTS, len(view_ids))
        views = list(record["views"])
        if len(views) != len(view_ids):
            raise ValueError(f"{len(views)} views for {len(view_ids)} view ids")
        by_id = {cam.view_id: cam for cam in cameras}
        out: dict[int, dict[int, tuple[float, float]]] = {}
        for c, (view_id, view) in enumerate(zip(view_ids, views, strict=True)):
            cam = by_id.get(view_id)
            if view is None or cam is None:
                continue
            xy = np.array(view["keypoints_px"], dtype=np.float64).reshape(NUM_KEYPOINTS, 2)  # None -> nan
            scores = np.nan_to_num(np.array(view["scores"], dtype=np.float64).reshape(NUM_KEYPOINTS), nan=0.0)
            presence = float(np.nan_to_num(float(view.get("presence") or 0.0)))
            use = used_detections(xy, scores, presence, inliers[:, c], cam.width, cam.height)
            if use.any():
                out[view_id] = {int(k): (float(xy[k, 0]), float(xy[k, 1])) for k in np.flatnonzero(use)}
        return out
    except (KeyError, TypeError, ValueError) as exc:  # a stored record this code cannot read: nothing to measure
        logger.warning("unreadable detection record in a fit's inputs (%s); no residuals against it", exc)
        return None
