"""The detector's per-view 2D keypoints as heat maps in MVNet's crop frame (heatmap_source = "detector").

Keypoints arrive in full-image pixels; a crop's affine map A = K_crop K^-1 (data.crop_transform, with any
training rotation / scale / shift folded into K_crop) takes them into crop pixels, and the feature map's
pixel grid is the crop's at 1 / stride (pixel-centre convention, as the auxiliary 2D targets in train.py).
"""

from __future__ import annotations

import numpy as np
import torch

from workers.nets.unproject import project_batched, voxel_centers


def image_to_crop_px(keypoints_px: np.ndarray, K_crop: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Image pixels -> crop pixels.

    Args:
        keypoints_px: (..., C, P, 2) pixels of each view's full image (NaN stays NaN).
        K_crop: (..., C, 3, 3) crop intrinsics (A K); K: (C, 3, 3) the cameras' intrinsics.
    Returns:
        (..., C, P, 2) float64 crop pixels.
    """
    A = np.asarray(K_crop, np.float64) @ np.linalg.inv(np.asarray(K, np.float64))  # (..., C, 3, 3), affine
    pts = np.asarray(keypoints_px, np.float64)
    return np.einsum("...ij,...pj->...pi", A[..., :2, :2], pts) + A[..., None, :2, 2]


def crop_to_map_px(crop_px: torch.Tensor, crop_size: int, map_size: int) -> torch.Tensor:
    """Crop pixels -> feature-map pixels (pixel centres: (u + 0.5) h / S - 0.5)."""
    return (crop_px + 0.5) * (map_size / crop_size) - 0.5


def render_keypoint_maps(keypoints_crop_px: torch.Tensor, weights: torch.Tensor, crop_size: int, map_size: int,
                         sigma_map_px: float) -> torch.Tensor:
    """Gaussian heat maps of 2D keypoints, one map per view and keypoint.

    Args:
        keypoints_crop_px: (B, C, K, 2) keypoints in crop pixels (x, y); NaN where a view has none.
        weights: (B, C, K) in [0, 1]: the detector's per-keypoint score (which already carries the view's
            presence) and 0 for views without a detection or outside the frame's subset; NaN counts as 0.
        crop_size: S, side of the crop, pixels; map_size: h, side of the map (the 2D feature map's).
        sigma_map_px: standard deviation of the Gaussians, pixels of the map.
    Returns:
        (B, C, K, h, h) float32: weight * exp(-d^2 / (2 sigma^2)), d the distance from each map pixel's centre
        to the keypoint; the peak (= the weight) lies at the keypoint's map pixel.
    """
    if keypoints_crop_px.shape[-1] != 2 or keypoints_crop_px.shape[:-1] != weights.shape:
        raise ValueError(f"keypoints (B, C, K, 2) and weights (B, C, K) disagree: {tuple(keypoints_crop_px.shape)}, "
                         f"{tuple(weights.shape)}")
    finite = torch.isfinite(keypoints_crop_px).all(-1) & torch.isfinite(weights)
    w = torch.where(finite, weights, torch.zeros_like(weights)).float()
    uv = crop_to_map_px(torch.nan_to_num(keypoints_crop_px.float(), nan=-1e4), crop_size, map_size)
    axis = torch.arange(map_size, device=uv.device, dtype=torch.float32)
    gx = torch.exp(-0.5 * ((axis - uv[..., 0, None]) / sigma_map_px) ** 2)  # (B, C, K, h) along x
    gy = torch.exp(-0.5 * ((axis - uv[..., 1, None]) / sigma_map_px) ** 2)  # along y
    return w[..., None, None] * gy[..., :, None] * gx[..., None, :]


@torch.no_grad()
def likelihood_volume(keypoints_crop_px: torch.Tensor, weights: torch.Tensor, K_crop: torch.Tensor,
                      dist: torch.Tensor, R: torch.Tensor, t: torch.Tensor, center_world: torch.Tensor, grid_size: int,
                      side_m: float, crop_size: int, sigma_crop_px: float, view_valid: torch.Tensor | None = None,
                      grid_rotation: torch.Tensor | None = None, floor: float = 1e-3) -> torch.Tensor:
    """The views' agreement on each keypoint at every voxel: a Gaussian likelihood of the voxel's reprojection
    distances to the detected keypoints (a triangulation as a volume, no rays).

    L_k(v) = exp(-sum_c w_ck d_ck(v)^2 / (2 sigma^2 sum_c w_ck)) * sum_c w_ck / sum_c' w_c'k, the sums over the views c
    that see voxel v (in front of the camera, inside the crop) and c' over all valid views: 1 where every view that
    found the keypoint projects the voxel exactly onto it; a voxel seen by few of them is damped by their share of
    the weight. Its width about the triangulated point is ~sigma * sqrt(3/2) at the hand's depth for views spread
    around it.

    Args:
        keypoints_crop_px: (B, C, K, 2) detected keypoints, crop pixels (NaN where none).
        weights: (B, C, K) their weights (NaN = 0). K_crop: (B, C, 3, 3); dist (C, 5) or (B, C, 5); R, t as in
            unproject.project_batched. center_world: (B, 3) grid centres, metres.
        grid_size, side_m: the grid; crop_size: crop side, pixels; sigma_crop_px: Gaussian width, crop pixels.
        view_valid: (B, C) bool; grid_rotation: (B, 3, 3) as in unproject.voxel_centers.
    Returns:
        (B, K, N, N, N) float32 in [0, 1].
    """
    B, K = weights.shape[0], weights.shape[2]
    N = grid_size
    points = voxel_centers(center_world.float(), N, side_m, grid_rotation).reshape(B, N**3, 3)
    pixels, depth = project_batched(points, K_crop.float(), dist.float(), R.float(), t.float())  # (B, C, P, 2)
    inside = (depth > 1e-3) & (pixels >= -0.5).all(-1) & (pixels <= crop_size - 0.5).all(-1)  # (B, C, P)
    finite = torch.isfinite(keypoints_crop_px).all(-1) & torch.isfinite(weights)
    w = torch.where(finite, weights, torch.zeros_like(weights)).float()  # (B, C, K)
    if view_valid is not None:
        w = w * view_valid[..., None].float()
    kp = torch.nan_to_num(keypoints_crop_px.float())
    # |p - k|^2 = |p|^2 - 2 p.k + |k|^2 without the (B, C, P, K, 2) difference tensor
    d2 = ((pixels**2).sum(-1)[..., None] - 2 * torch.einsum("bcpx,bckx->bcpk", pixels, kp)
          + (kp**2).sum(-1)[:, :, None, :]).clamp(min=0)  # (B, C, P, K)
    wi = w[:, :, None, :] * inside[..., None].float()  # (B, C, P, K)
    seen = wi.sum(1)  # (B, P, K)
    mean_d2 = (wi * d2).sum(1) / seen.clamp(min=1e-12)
    likelihood = torch.exp(-mean_d2 / (2 * sigma_crop_px**2)) * (seen / w.sum(1)[:, None, :].clamp(min=floor))
    return likelihood.permute(0, 2, 1).reshape(B, K, N, N, N).contiguous()
