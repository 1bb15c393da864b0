"""The annotate page's triangulated proposal, ported from frontend/js/geometry.js (`projectPoint`,
`undistortPixel`, `triangulate`) and frontend/js/annotation.js (`triangulateClicked`, `inside`), so the
simulated annotator is offered what a person is offered.

The geometry is workers/geometry's (`project_array`, `undistort_normalized`, `dlt_homogeneous`); only the
page's policy is here: not workers/geometry's `triangulate`, which picks the best two-view hypothesis
(RANSAC-like) and undistorts with OpenCV to convergence, the page drops the worst view one at a time and
undistorts with 20 fixed-point steps. Cameras are the proposals endpoint's `cameras` entries
(`ViewCamera.to_public()`: view_id, width, height, K (3x3 px), dist (k1, k2, p1, p2, k3), R, t with
X_c = R X_w + t in metres), as the page uses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from workers.geometry.projection import project_array, undistort_normalized
from workers.geometry.triangulation import dlt_homogeneous

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


def _arrays(cams: list[dict]) -> dict[str, np.ndarray]:
    """Payload cameras as `project_array`'s stacked arrays: K (C, 3, 3), dist (C, 5), R (C, 3, 3), t (C, 3)."""
    return {key: np.asarray([cam[key] for cam in cams], np.float64) for key in ("K", "dist", "R", "t")}


def project_point(X: np.ndarray, cam: dict) -> tuple[float, float] | None:
    """World point (3,) metres -> (u, v) distorted pixels, or None behind the camera (depth <= 1e-6 m)."""
    pixels, depth = project_array(np.asarray(X, np.float64).reshape(1, 1, 3), **_arrays([cam]))
    if not depth[0, 0, 0] > 1e-6:
        return None
    return float(pixels[0, 0, 0, 0]), float(pixels[0, 0, 0, 1])


def undistort_pixel(uv: tuple[float, float], cam: dict, iterations: int = 20) -> tuple[float, float]:
    """Pixel -> ideal normalised (x/z, y/z) by OpenCV's fixed-point inverse, `iterations` steps as the page
    (K with its skew)."""
    K = cam["K"]
    yd = (uv[1] - K[1][2]) / K[1][1]
    xd = (uv[0] - K[0][2] - K[0][1] * yd) / K[0][0]
    return undistort_normalized(xd, yd, [float(k) for k in cam["dist"]], iterations)


def triangulate(observations: list[tuple[dict, tuple[float, float]]],
                outlier_px: float = OUTLIER_PX) -> tuple[np.ndarray, list[float], list[int]] | None:
    """geometry.js `triangulate`: observations [(camera, (u, v) px)] -> (point (3,) m, errors px, used view ids),
    the worst view dropped while its error exceeds `outlier_px` and 3 or more remain; None with fewer than 2
    views, a point at infinity, or a used view the point lies behind.

    workers/geometry's weighted DLT (`dlt_homogeneous`) on ideal normalised xy with P = [R | t], all weights 1
    (rows normalised by the norm of their first three entries, as the page's)."""
    obs = [(cam, (float(p[0]), float(p[1]))) for cam, p in observations
           if p is not None and math.isfinite(p[0]) and math.isfinite(p[1])]
    if len(obs) < 2:
        return None
    cams = _arrays([cam for cam, _ in obs])
    pixels = np.array([p for _, p in obs])
    ideal = np.array([undistort_pixel(p, cam) for cam, p in obs])  # the page redoes it each pass: the same numbers
    P = np.concatenate([cams["R"], cams["t"][:, :, None]], axis=2)  # (C, 3, 4)
    alive = np.arange(len(obs))
    while len(alive) >= 2:
        X = dlt_homogeneous(P[alive], ideal[alive], np.ones(len(alive)))
        if abs(X[3]) < 1e-12:
            return None
        point = X[:3] / X[3]
        projected, depth = project_array(point.reshape(1, 1, 3), **{k: v[alive] for k, v in cams.items()})
        errors = np.hypot(*(projected[0, :, 0] - pixels[alive]).T)
        errors[~(depth[0, :, 0] > 1e-6)] = math.inf
        worst = int(np.argmax(errors))  # the first of equal maxima, as the page's loop
        if errors[worst] <= outlier_px or len(alive) < 3:
            if not np.isfinite(errors).all():
                return None
            return point, errors.tolist(), [obs[i][0]["view_id"] for i in alive]
        alive = np.delete(alive, worst)
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
