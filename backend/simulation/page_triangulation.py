"""The annotate page's triangulated proposal, ported from frontend/js/geometry.js (`projectPoint`,
`undistortPixel`, `triangulate`) and frontend/js/annotation.js (`triangulateClicked`, `inside`), so the
simulated annotator is offered what a person is offered.

Not workers/geometry's `triangulate`: that one picks the best two-view hypothesis (RANSAC-like) and
undistorts with OpenCV; the page drops the worst view one at a time and undistorts with 20 fixed-point
steps. Cameras are the proposals endpoint's `cameras` entries (`ViewCamera.to_public()`: view_id, width,
height, K (3x3 px), dist (k1, k2, p1, p2, k3), R, t with X_c = R X_w + t in metres), as the page uses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

OUTLIER_PX = 12.0  # geometry.js triangulate(): a view above this reprojection error is dropped (while >= 3 remain)
TRIANGULATION_ZERO_CONF_PX = 12.0  # annotation.js: confidence 1 at 0 px worst error, 0 at this many px


@dataclass(frozen=True)
class PageTriangulation:
    """point: (3,) metres, world frame; errors_px: per used view, pixels; used: their view ids; confidence in [0, 1]."""

    point: np.ndarray
    errors_px: tuple[float, ...]
    used: tuple[int, ...]
    confidence: float


def inside(p: tuple[float, float] | np.ndarray | None, cam: dict) -> bool:
    """annotation.js `inside`: a pixel within the image, pixel centres from (0, 0) to (width - 1, height - 1)."""
    return p is not None and -0.5 <= p[0] <= cam["width"] - 0.5 and -0.5 <= p[1] <= cam["height"] - 0.5


def project_point(X: np.ndarray, cam: dict) -> tuple[float, float] | None:
    """World point (3,) metres -> (u, v) distorted pixels, or None behind the camera (depth <= 1e-6 m)."""
    Xc = np.asarray(cam["R"], float) @ np.asarray(X, float) + np.asarray(cam["t"], float)
    if not Xc[2] > 1e-6:
        return None
    x, y = Xc[0] / Xc[2], Xc[1] / Xc[2]
    k1, k2, p1, p2, k3 = cam["dist"]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = cam["K"]
    return K[0][0] * xd + K[0][1] * yd + K[0][2], K[1][1] * yd + K[1][2]


def undistort_pixel(uv: tuple[float, float], cam: dict, iterations: int = 20) -> tuple[float, float]:
    """Pixel -> ideal normalised (x/z, y/z) by OpenCV's fixed-point inverse, `iterations` steps as the page."""
    K = cam["K"]
    k1, k2, p1, p2, k3 = cam["dist"]
    yd = (uv[1] - K[1][2]) / K[1][1]
    xd = (uv[0] - K[0][2] - K[0][1] * yd) / K[0][0]
    x, y = xd, yd
    for _ in range(iterations):
        r2 = x * x + y * y
        icdist = 1 / (1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) * icdist, (yd - dy) * icdist
    return x, y


def _dlt(observations: list[tuple[dict, tuple[float, float]]]) -> np.ndarray | None:
    """Rows x P3 - P1, y P3 - P2 (P = [R | t], ideal normalised xy), each over the norm of its first three
    entries; the point is M's eigenvector of the smallest eigenvalue (M = sum of row row^T, 4x4)."""
    M = np.zeros((4, 4))
    for cam, xy in observations:
        P = np.hstack([np.asarray(cam["R"], float), np.asarray(cam["t"], float)[:, None]])
        for coord, r in ((xy[0], 0), (xy[1], 1)):
            row = coord * P[2] - P[r]
            norm = math.hypot(*row[:3]) or 1.0
            M += np.outer(row, row) / (norm * norm)
    values, vectors = np.linalg.eigh(M)
    X = vectors[:, int(np.argmin(values))]
    if abs(X[3]) < 1e-12:
        return None
    return X[:3] / X[3]


def triangulate(observations: list[tuple[dict, tuple[float, float]]],
                outlier_px: float = OUTLIER_PX) -> tuple[np.ndarray, list[float], list[int]] | None:
    """geometry.js `triangulate`: observations [(camera, (u, v) px)] -> (point (3,) m, errors px, used view ids),
    the worst view dropped while its error exceeds `outlier_px` and 3 or more remain; None with fewer than 2
    views, a point at infinity, or a used view the point lies behind."""
    obs = [(cam, (float(p[0]), float(p[1]))) for cam, p in observations
           if p is not None and math.isfinite(p[0]) and math.isfinite(p[1])]
    while len(obs) >= 2:
        point = _dlt([(cam, undistort_pixel(p, cam)) for cam, p in obs])
        if point is None:
            return None
        errors = []
        for cam, p in obs:
            q = project_point(point, cam)
            errors.append(math.inf if q is None else math.hypot(q[0] - p[0], q[1] - p[1]))
        worst = int(np.argmax(errors))  # the first of equal maxima, as the page's loop
        if errors[worst] <= outlier_px or len(obs) < 3:
            if not all(math.isfinite(e) for e in errors):
                return None
            return point, errors, [cam["view_id"] for cam, _ in obs]
        obs.pop(worst)
    return None


def triangulate_clicked(clicked: list[tuple[dict, tuple[float, float]]]) -> PageTriangulation | None:
    """annotation.js `triangulateClicked`: the keypoint from the views where it was placed by hand (the caller
    passes only those, never accepted proposals), confidence 1 - worst error / 12 px (floored at 0); None
    with fewer than 2 views."""
    if len(clicked) < 2:
        return None
    tri = triangulate(clicked)
    if tri is None:
        return None
    point, errors, used = tri
    confidence = max(0.0, 1 - max(errors) / TRIANGULATION_ZERO_CONF_PX)
    return PageTriangulation(point, tuple(errors), tuple(used), confidence)


def triangulated_proposal(clicked: list[tuple[dict, tuple[float, float]]], cam: dict) -> tuple[float, float] | None:
    """annotation.js `proposals`: the triangulated point projected into `cam`, offered when it lies inside the
    image (whatever its confidence: the page rings a doubtful one but still shows it first); else None."""
    tri = triangulate_clicked(clicked)
    if tri is None:
        return None
    p = project_point(tri.point, cam)
    return (float(p[0]), float(p[1])) if inside(p, cam) else None
