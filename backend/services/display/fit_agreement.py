"""A fit's per-keypoint confidence as a proposal: how well its projection agrees with what it was fitted to
(the detector's own keypoints for a pre-annotation fit, else the points the annotator placed by hand).

Same scale as the page's triangulated proposals (frontend/js/annotation.js, TRIANGULATION_ZERO_CONF_PX):
1 at 0 px, falling linearly to 0 at ZERO_CONF_PX, from the median distance over the views that observed
the keypoint; None where no view observed it (the page then leaves it for a look).
"""

from __future__ import annotations

import numpy as np

ZERO_CONF_PX = 12.0  # full-resolution pixels, as the page's triangulation confidence
NUM_KEYPOINTS = 21


def fit_confidences(fit_px: dict[int, np.ndarray], observed: dict[int, dict[int, tuple[float, float]]]
                    ) -> list[float | None]:
    """fit_px: view id -> (21, 2) projected keypoints (pixels, NaN where not projectable); observed: view id ->
    keypoint -> (x, y) pixels. Returns 21 confidences in [0, 1] (rounded to 4 places) or None."""
    distances: list[list[float]] = [[] for _ in range(NUM_KEYPOINTS)]
    for view_id, points in observed.items():
        projected = fit_px.get(view_id)
        if projected is None:
            continue
        for keypoint, (x, y) in points.items():
            p = projected[keypoint]
            if 0 <= keypoint < NUM_KEYPOINTS and np.isfinite(p).all():
                distances[keypoint].append(float(np.hypot(p[0] - x, p[1] - y)))
    return [round(max(0.0, 1.0 - float(np.median(d)) / ZERO_CONF_PX), 4) if d else None for d in distances]
