"""Differentiable unprojection of per-view 2D feature maps into a voxel grid (paper: MVNet, after Kar et
al. 2017): every voxel centre is projected into every view (with lens distortion) and the view's feature
map is sampled bilinearly there; voxels behind a camera or outside its crop contribute nothing, and
the remaining views are averaged.

Grid convention: a cube of side `side_m` centred on `center_world`, axis-aligned with the world frame;
volume index (i, j, l) along (x, y, z) world; voxel (i, j, l) has its centre at
center + ((i, j, l) - (N - 1) / 2) * side_m / N. Shapes: B frames, C views, F channels, N voxels per side.
"""

from __future__ import annotations

import torch
import torch.nn.functional as nnf

from workers.geometry.projection import distort_normalized


def voxel_offsets(grid_size: int, side_m: float, device: torch.device | str = "cpu",
                  dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Voxel centres relative to the grid centre: (N, N, N, 3) metres, index (i, j, l) -> (x, y, z)."""
    step = side_m / grid_size
    axis = (torch.arange(grid_size, device=device, dtype=dtype) - (grid_size - 1) / 2) * step
    gx, gy, gz = torch.meshgrid(axis, axis, axis, indexing="ij")
    return torch.stack([gx, gy, gz], dim=-1)


def voxel_centers(center_world: torch.Tensor, grid_size: int, side_m: float,
                  rotation: torch.Tensor | None = None) -> torch.Tensor:
    """Voxel centres (B, N, N, N, 3), metres, world frame, of grids centred on center_world (B, 3).

    rotation: optional (B, 3, 3) orientation of the grid: its columns are the world directions of the voxel
    axes i, j, l (default: the world axes; training augmentation turns the grid).
    """
    offsets = voxel_offsets(grid_size, side_m, center_world.device, center_world.dtype)
    if rotation is None:
        return center_world[:, None, None, None, :] + offsets[None]
    return center_world[:, None, None, None, :] + torch.einsum("bxy,ijky->bijkx", rotation, offsets)


def project_batched(points_world: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, R: torch.Tensor,
                    t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Project points with per-frame intrinsics (crops have their own K).

    Args:
        points_world: (B, P, 3) metres, world frame.
        K: (B, C, 3, 3) pixel intrinsics of each frame's views (e.g. crop intrinsics).
        dist: (C, 5) OpenCV distortion; R: (C, 3, 3), t: (C, 3) world -> camera (shared by the batch), or
            (B, C, 5), (B, C, 3, 3), (B, C, 3) when each frame has its own cameras.
    Returns:
        pixels (B, C, P, 2) in the image K refers to; depth_m (B, C, P).
    """
    if R.ndim == 4:  # per-frame camera subsets
        points_cam = torch.einsum("bcij,bpj->bcpi", R, points_world) + t[:, :, None, :]
    else:
        points_cam = torch.einsum("cij,bpj->bcpi", R, points_world) + t[None, :, None, :]
    depth = points_cam[..., 2]
    xy = points_cam[..., :2] / depth.clamp(min=1e-4)[..., None]
    xy = distort_normalized(xy, dist)  # (B, C, P, 2); dist (C, 5) or per frame (B, C, 5)
    ones = torch.ones_like(xy[..., :1])
    uv = torch.einsum("bcij,bcpj->bcpi", K, torch.cat([xy, ones], dim=-1))
    return uv[..., :2], depth


def unproject_features(features: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, R: torch.Tensor,
                       t: torch.Tensor, center_world: torch.Tensor, grid_size: int, side_m: float,
                       image_px: int, view_valid: torch.Tensor | None = None,
                       grid_rotation: torch.Tensor | None = None, return_count: bool = False
                       ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Average the views' features over a voxel grid.

    Args:
        features: (B, C, F, h, w) feature maps of square crops of side `image_px` (any h = w: the map
            spans the whole crop).
        K: (B, C, 3, 3) intrinsics of the crops, pixels of the crop (pixel (0, 0) = centre of the top-left).
        dist: (C, 5); R: (C, 3, 3); t: (C, 3) world -> camera (or (B, C, ...) when each frame uses its
            own subset of the rig's cameras).
        center_world: (B, 3) grid centres, metres, world frame.
        grid_size: N; side_m: grid side, metres; image_px: crop side, pixels.
        view_valid: (B, C) bool, views to use (default all).
        grid_rotation: (B, 3, 3) grid orientation (see `voxel_centers`); default world-aligned.
        return_count: also return how many views see each voxel, (B, N, N, N).
    Returns:
        (B, F, N, N, N) averaged features (memory in channels-last-3d order, what the 3D convolutions
        prefer), index (i, j, l) along the grid axes (world x, y, z unless rotated); zero where no view
        sees the voxel [, count].

    Bilinear sampling (as grid_sample with align_corners=False and zero padding) and the average over
    views are one weighted sum of 4 C feature-map pixels per voxel, computed by `embedding_bag`: its
    backward accumulates into the few feature pixels directly, about twice as fast on the CPU as
    grid_sample's backward followed by a separate average (which this replaced).
    """
    B, C, F, h, w = features.shape
    if K.shape != (B, C, 3, 3) or center_world.shape != (B, 3):
        raise ValueError(f"K must be (B={B}, C={C}, 3, 3) and center_world (B, 3); got {tuple(K.shape)}, "
                         f"{tuple(center_world.shape)}")
    N = grid_size
    P = N**3
    with torch.no_grad():  # geometry: no gradient needed
        points = voxel_centers(center_world, N, side_m, grid_rotation).reshape(B, P, 3)
        pixels, depth = project_batched(points, K, dist, R, t)  # (B, C, P, 2), (B, C, P)
        inside = (depth > 1e-3) & (pixels >= -0.5).all(dim=-1) & (pixels <= image_px - 0.5).all(dim=-1)
        if view_valid is not None:
            inside = inside & view_valid[:, :, None]
        count = inside.sum(dim=1).to(features.dtype)  # (B, P)
        # crop pixel -> feature-map pixel (pixel centres at integers), 4 neighbours and their weights
        pixels = torch.where(inside[..., None], pixels, torch.zeros_like(pixels))  # no inf / NaN below
        x = (pixels[..., 0] + 0.5) * (w / image_px) - 0.5
        y = (pixels[..., 1] + 0.5) * (h / image_px) - 0.5
        x0, y0 = torch.floor(x), torch.floor(y)
        fx, fy = x - x0, y - y0
        x0, y0 = x0.long(), y0.long()
        scale = inside.to(features.dtype) / count.clamp(min=1)[:, None, :]  # (B, C, P): the view average
        base = (torch.arange(B, device=features.device)[:, None] * C
                + torch.arange(C, device=features.device)[None, :]) * (h * w)  # (B, C) first row of each map
        indices, weights = [], []
        for dy, wy in ((0, 1 - fy), (1, fy)):
            for dx, wx in ((0, 1 - fx), (1, fx)):
                xi, yi = x0 + dx, y0 + dy
                ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
                indices.append(base[:, :, None] + yi.clamp(0, h - 1) * w + xi.clamp(0, w - 1))
                weights.append(wy * wx * scale * ok.to(features.dtype))
        # (B, C, P, 4) -> one bag of 4 C entries per voxel: (B P, 4 C)
        indices_t = torch.stack(indices, dim=-1).permute(0, 2, 1, 3).reshape(B * P, C * 4)
        weights_t = torch.stack(weights, dim=-1).permute(0, 2, 1, 3).reshape(B * P, C * 4)
    table = features.permute(0, 1, 3, 4, 2).reshape(B * C * h * w, F)
    sampled = nnf.embedding_bag(indices_t, table, per_sample_weights=weights_t, mode="sum")  # (B P, F)
    volume = sampled.reshape(B, N, N, N, F).permute(0, 4, 1, 2, 3)
    return (volume, count.reshape(B, N, N, N)) if return_count else volume
