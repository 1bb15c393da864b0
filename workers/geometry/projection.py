"""Projection of world points into calibrated views, with OpenCV distortion.

The torch functions are differentiable (the fitting engine uses them); numpy wrappers serve everything
else. Shapes: C cameras, N points, B batch. Units: metres in, pixels out.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from workers.geometry.camera import Camera


def stack_cameras(cameras: list[Camera], dtype: torch.dtype = torch.float32,
                  device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
    """Camera parameters as tensors: K (C,3,3), dist (C,5), R (C,3,3), t (C,3)."""
    def as_tensor(key: str) -> torch.Tensor:
        return torch.as_tensor(np.stack([getattr(c, key) for c in cameras]), dtype=dtype, device=device)

    return {key: as_tensor(key) for key in ("K", "dist", "R", "t")}


def distort_normalized(xy: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """Apply OpenCV distortion to normalised image coordinates.

    Args:
        xy: (..., C, N, 2) normalised coordinates x/z, y/z.
        dist: (C, 5) k1, k2, p1, p2, k3.
    Returns:
        (..., C, N, 2) distorted normalised coordinates.
    """
    k1, k2, p1, p2, k3 = (dist[:, i, None] for i in range(5))  # each (C, 1)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return torch.stack([xd, yd], dim=-1)


def project_points_torch(points_world: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, R: torch.Tensor,
                         t: torch.Tensor, min_depth_m: float = 1e-4) -> tuple[torch.Tensor, torch.Tensor]:
    """Project world points into every camera.

    Args:
        points_world: (B, N, 3) metres, world frame.
        K, dist, R, t: (C,3,3), (C,5), (C,3,3), (C,3) from `stack_cameras`.
        min_depth_m: depths below this are clamped before division (points behind a camera get
            meaningless pixels; check the returned depth).
    Returns:
        pixels: (B, C, N, 2) pixel coordinates (0, 0 = centre of the top-left pixel).
        depth_m: (B, C, N) depth along each camera's z axis, metres.
    """
    points_cam = torch.einsum("cij,bnj->bcni", R, points_world) + t[None, :, None, :]
    depth = points_cam[..., 2]
    xy = points_cam[..., :2] / depth.clamp(min=min_depth_m)[..., None]
    xy = distort_normalized(xy, dist)
    fx, fy = K[:, 0, 0, None], K[:, 1, 1, None]
    cx, cy, skew = K[:, 0, 2, None], K[:, 1, 2, None], K[:, 0, 1, None]
    u = fx * xy[..., 0] + skew * xy[..., 1] + cx
    v = fy * xy[..., 1] + cy
    return torch.stack([u, v], dim=-1), depth


def project_points(points_world: np.ndarray, cameras: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """numpy wrapper: points (N, 3) metres -> pixels (C, N, 2), depth_m (C, N), float64."""
    points = torch.as_tensor(np.asarray(points_world, dtype=np.float64)[None])
    pixels, depth = project_points_torch(points, **stack_cameras(cameras, dtype=torch.float64))
    return pixels[0].numpy(), depth[0].numpy()


def undistort_pixels(pixels: np.ndarray, camera: Camera) -> np.ndarray:
    """Remove lens distortion: distorted pixels (N, 2) -> ideal pinhole pixels (N, 2) of the same K.

    Uses OpenCV's iterative inverse (cv2.undistortPoints with an explicit stopping criterion).
    """
    pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if pts.shape[0] == 0:
        return np.zeros((0, 2))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    out = cv2.undistortPoints(pts, camera.K, camera.dist, R=None, P=camera.K, criteria=criteria)
    return out.reshape(-1, 2)
