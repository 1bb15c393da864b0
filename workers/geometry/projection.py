"""Projection of world points into calibrated views, with OpenCV distortion: written once.

`project_array` is the formula, for numpy arrays or torch tensors alike (`workers.geometry.arrays`); the
torch face (`project_points_torch`, with `stack_cameras`) is differentiable and the fitting engine and the
networks use it; the numpy faces (`project_points` for a rig, `project_visible` for one view with NaN
where a point cannot be seen) serve everything else, the API's overlays included. Neither torch nor
OpenCV is imported by this module at import time, so the API process may use it.

Conventions (docs/conventions.md): X_c = R X_w + t, OpenCV pinhole with (k1, k2, p1, p2, k3), pixel
(0, 0) the centre of the top-left pixel. Shapes: C cameras, N points, B batch. Units: metres in, pixels out.
tests/workers/geometry/test_projection_triangulation.py holds it equal to `cv2.projectPoints`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from workers.geometry.arrays import Array, clip_min, namespace
from workers.geometry.camera import Camera

if TYPE_CHECKING:
    import torch


def stack_cameras(cameras: list[Camera], dtype: torch.dtype | None = None,
                  device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
    """Camera parameters as tensors: K (C,3,3), dist (C,5), R (C,3,3), t (C,3); dtype defaults to float32."""
    import torch  # deferred: the torch face only; the numpy faces of this module stay torch-free

    def as_tensor(key: str) -> torch.Tensor:
        return torch.as_tensor(np.stack([getattr(c, key) for c in cameras]), dtype=dtype or torch.float32,
                               device=device)

    return {key: as_tensor(key) for key in ("K", "dist", "R", "t")}


def camera_arrays(cameras: list[Camera]) -> dict[str, np.ndarray]:
    """`stack_cameras` in numpy, float64: K (C,3,3), dist (C,5), R (C,3,3), t (C,3)."""
    return {key: np.stack([np.asarray(getattr(c, key), np.float64) for c in cameras])
            for key in ("K", "dist", "R", "t")}


def distort_normalized(xy: Array, dist: Array) -> Array:
    """Apply OpenCV distortion to normalised image coordinates.

    Args:
        xy: (..., C, N, 2) normalised coordinates x/z, y/z.
        dist: (C, 5) k1, k2, p1, p2, k3, or (..., C, 5) per leading index (e.g. per frame).
    Returns:
        (..., C, N, 2) distorted normalised coordinates.
    """
    k1, k2, p1, p2, k3 = (dist[..., i, None] for i in range(5))  # each (..., C, 1)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return namespace(xy).stack([xd, yd], axis=-1)


def undistort_normalized(xd: Any, yd: Any, dist: Any, iterations: int = 20) -> tuple[Any, Any]:
    """The inverse of `distort_normalized` by OpenCV's fixed-point iteration (the steps of `cv2.undistortPoints`,
    a fixed number of them): distorted normalised (xd, yd) -> ideal normalised (x, y).

    Elementwise: xd, yd are Python floats (fastest for one point: the simulated annotator undistorts a few
    clicks at a time) or numpy arrays of one shape; dist is (k1, k2, p1, p2, k3), each a float or an array
    broadcasting with xd.
    """
    k1, k2, p1, p2, k3 = dist
    x, y = xd, yd
    for _ in range(iterations):
        r2 = x * x + y * y
        icdist = 1 / (1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) * icdist, (yd - dy) * icdist
    return x, y


def project_array(points_world: Array, K: Array, dist: Array, R: Array, t: Array,
                  min_depth_m: float = 1e-4) -> tuple[Array, Array]:
    """Project world points into every camera (numpy or torch, all inputs of one kind).

    Args:
        points_world: (B, N, 3) metres, world frame.
        K, dist, R, t: (C,3,3), (C,5), (C,3,3), (C,3) from `stack_cameras` / `camera_arrays`.
        min_depth_m: depths below this are clamped before division (points behind a camera get
            meaningless pixels; check the returned depth).
    Returns:
        pixels: (B, C, N, 2) pixel coordinates (0, 0 = centre of the top-left pixel).
        depth_m: (B, C, N) depth along each camera's z axis, metres.
    """
    xp = namespace(points_world)
    points_cam = xp.einsum("cij,bnj->bcni", R, points_world) + t[None, :, None, :]
    depth = points_cam[..., 2]
    xy = points_cam[..., :2] / clip_min(depth, min_depth_m)[..., None]
    xy = distort_normalized(xy, dist)
    fx, fy = K[:, 0, 0, None], K[:, 1, 1, None]
    cx, cy, skew = K[:, 0, 2, None], K[:, 1, 2, None], K[:, 0, 1, None]
    u = fx * xy[..., 0] + skew * xy[..., 1] + cx
    v = fy * xy[..., 1] + cy
    return xp.stack([u, v], axis=-1), depth


def project_points_torch(points_world: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, R: torch.Tensor,
                         t: torch.Tensor, min_depth_m: float = 1e-4) -> tuple[torch.Tensor, torch.Tensor]:
    """The torch face of `project_array` (same arguments and returns), differentiable."""
    return project_array(points_world, K, dist, R, t, min_depth_m)


def project_points(points_world: np.ndarray, cameras: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """numpy face: points (N, 3) metres -> pixels (C, N, 2), depth_m (C, N), float64."""
    points = np.asarray(points_world, dtype=np.float64).reshape(1, -1, 3)
    pixels, depth = project_array(points, **camera_arrays(cameras))
    return pixels[0], depth[0]


def project_visible(points_world: np.ndarray, camera: Camera, min_depth_m: float = 1e-6) -> np.ndarray:
    """One view: points (N, 3) metres, world frame -> (N, 2) pixels; NaN for points not finite or not in front
    of the camera (depth <= min_depth_m), the rule the pages use."""
    points = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(points), 2), np.nan)
    finite = np.isfinite(points).all(axis=1)
    if finite.any():
        pixels, depth = project_points(points[finite], [camera])
        seen = depth[0] > min_depth_m
        out[np.flatnonzero(finite)[seen]] = pixels[0][seen]
    return out


def undistort_pixels(pixels: np.ndarray, camera: Camera, iterations: int = 50) -> np.ndarray:
    """Remove lens distortion: distorted pixels (N, 2) -> ideal pinhole pixels (N, 2) of the same K.

    Uses OpenCV's iterative inverse (cv2.undistortPoints) with an explicit stopping criterion: at most
    `iterations` fixed-point steps, fewer once a step moves less than 1e-12.
    """
    import cv2  # deferred: OpenCV out of the API's start-up; the API only projects

    pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if pts.shape[0] == 0:
        return np.zeros((0, 2))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, 1e-12)
    out = cv2.undistortPoints(pts, camera.K, camera.dist, R=None, P=camera.K, criteria=criteria)
    return out.reshape(-1, 2)
