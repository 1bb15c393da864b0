"""MVNet losses, keypoint read-out and confidence (paper eq. 7 and 8; supplementary "MVNet").

Score volumes S (B, K, N, N, N) are indexed (i, j, l) along world (x, y, z) as in `unproject.py`.
Keypoints in grid coordinates are continuous voxel indices (voxel centres at integers).

- Score-volume loss: squared L2 between each predicted volume and a Gaussian of standard deviation
  `sigma_voxels` centred on the true keypoint, normalised to a peak of 1 (so the maximum score lives in
  [0, 1] and the paper's confidence thresholds 0.8 / 0.6 apply), summed over voxels, averaged over K.
- Soft-argmax loss (Iqbal et al. 2018): the expected location under softmax(S) against the true one
  (L1, voxels); its confidence is the maximum of the softmax "latent heat map".
"""

from __future__ import annotations

import torch


def world_to_grid(points_world: torch.Tensor, center_world: torch.Tensor, grid_size: int,
                  side_m: float, rotation: torch.Tensor | None = None) -> torch.Tensor:
    """points (B, K, 3) metres, world frame; centres (B, 3); optional grid orientation (B, 3, 3) (columns =
    world directions of the voxel axes) -> (B, K, 3) continuous voxel indices."""
    offsets = points_world - center_world[:, None, :]
    if rotation is not None:
        offsets = torch.einsum("bxy,bkx->bky", rotation, offsets)  # R^T (p - c)
    return offsets / (side_m / grid_size) + (grid_size - 1) / 2


def grid_to_world(points_grid: torch.Tensor, center_world: torch.Tensor, grid_size: int,
                  side_m: float, rotation: torch.Tensor | None = None) -> torch.Tensor:
    """Inverse of `world_to_grid`: (B, K, 3) voxel indices -> (B, K, 3) metres, world frame."""
    offsets = (points_grid - (grid_size - 1) / 2) * (side_m / grid_size)
    if rotation is not None:
        offsets = torch.einsum("bxy,bky->bkx", rotation, offsets)
    return offsets + center_world[:, None, :]


def gaussian_targets(keypoints_grid: torch.Tensor, grid_size: int, sigma_voxels: float) -> torch.Tensor:
    """Peak-normalised Gaussian score targets.

    Args:
        keypoints_grid: (B, K, 3) continuous voxel indices.
    Returns:
        (B, K, N, N, N) exp(-|x - p|^2 / (2 sigma^2)), 1 at the keypoint.
    """
    axis = torch.arange(grid_size, device=keypoints_grid.device, dtype=keypoints_grid.dtype)
    d = [(axis[None, None, :] - keypoints_grid[..., a, None]) ** 2 for a in range(3)]  # each (B, K, N)
    inv = -1.0 / (2 * sigma_voxels**2)
    return torch.exp(inv * (d[0][..., :, None, None] + d[1][..., None, :, None] + d[2][..., None, None, :]))


def scorevolume_loss(scores: torch.Tensor, targets: torch.Tensor, weights: torch.Tensor | None = None) -> torch.Tensor:
    """Paper eq. 7: (1/K) sum_k ||S_k - S~_k||^2 (summed over voxels), averaged over the batch.

    scores, targets: (B, K, N, N, N); weights: (B, K) optional per-keypoint weights (0 = unlabelled).
    """
    per_kp = ((scores - targets) ** 2).flatten(2).sum(-1)  # (B, K)
    if weights is None:
        return per_kp.mean()
    return (per_kp * weights).sum() / weights.sum().clamp(min=1)


def softmax_volume(scores: torch.Tensor) -> torch.Tensor:
    """(B, K, N, N, N) -> per-keypoint probability volumes (softmax over the voxels)."""
    B, K = scores.shape[:2]
    return torch.softmax(scores.flatten(2), dim=-1).reshape(scores.shape).view(B, K, *scores.shape[2:])


def soft_argmax(scores: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Expected voxel location under softmax(S).

    Returns:
        keypoints_grid (B, K, 3) continuous voxel indices; confidence (B, K) = max of the softmax volume.
    """
    N = scores.shape[-1]
    prob = softmax_volume(scores)
    axis = torch.arange(N, device=scores.device, dtype=scores.dtype)
    ex = (prob.sum(dim=(3, 4)) * axis).sum(-1)
    ey = (prob.sum(dim=(2, 4)) * axis).sum(-1)
    ez = (prob.sum(dim=(2, 3)) * axis).sum(-1)
    return torch.stack([ex, ey, ez], dim=-1), prob.flatten(2).amax(-1)


def softargmax_loss(scores: torch.Tensor, keypoints_grid: torch.Tensor,
                    weights: torch.Tensor | None = None) -> torch.Tensor:
    """Mean L1 distance (voxels) between the soft-argmax and the true keypoints (B, K, 3)."""
    predicted, _ = soft_argmax(scores)
    per_kp = (predicted - keypoints_grid).abs().sum(-1)  # (B, K)
    if weights is None:
        return per_kp.mean()
    return (per_kp * weights).sum() / weights.sum().clamp(min=1)


def refined_argmax(scores: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The maximal voxel of each score volume, refined below voxel size.

    Refinement fits a parabola to log(score) through the maximum and its two neighbours along each axis
    (exact for a Gaussian peak); the offset is clipped to half a voxel and skipped where a neighbour is
    outside the grid or a score is not positive.

    Args:
        scores: (B, K, N, N, N).
    Returns:
        keypoints_grid (B, K, 3) continuous voxel indices; confidence (B, K) = the maximal score (eq. 8).
    """
    B, K, N = scores.shape[0], scores.shape[1], scores.shape[-1]
    flat = scores.reshape(B, K, -1)
    confidence, index = flat.max(dim=-1)
    ijk = torch.stack([index // (N * N), (index // N) % N, index % N], dim=-1)  # (B, K, 3)
    out = ijk.to(scores.dtype).clone()
    for axis in range(3):
        lo, hi = ijk.clone(), ijk.clone()
        lo[..., axis] = (ijk[..., axis] - 1).clamp(min=0)
        hi[..., axis] = (ijk[..., axis] + 1).clamp(max=N - 1)
        s_lo = flat.gather(-1, (lo[..., 0] * N * N + lo[..., 1] * N + lo[..., 2])[..., None])[..., 0]
        s_hi = flat.gather(-1, (hi[..., 0] * N * N + hi[..., 1] * N + hi[..., 2])[..., None])[..., 0]
        ok = (ijk[..., axis] > 0) & (ijk[..., axis] < N - 1) & (s_lo > 0) & (s_hi > 0) & (confidence > 0)
        eps = 1e-12
        l0, lm, lp = confidence.clamp(min=eps).log(), s_lo.clamp(min=eps).log(), s_hi.clamp(min=eps).log()
        denom = lm - 2 * l0 + lp
        offset = torch.where(denom < -1e-9, 0.5 * (lm - lp) / denom.clamp(max=-1e-9), torch.zeros_like(denom))
        out[..., axis] = out[..., axis] + torch.where(ok, offset.clamp(-0.5, 0.5), torch.zeros_like(offset))
    return out, confidence


def gaussian_targets_2d(keypoints_px: torch.Tensor, size: int, sigma_px: float) -> torch.Tensor:
    """Peak-normalised 2D Gaussians: keypoints (..., K, 2) (u, v) in pixels of a (size x size) map ->
    (..., K, size, size) indexed [v, u]."""
    axis = torch.arange(size, device=keypoints_px.device, dtype=keypoints_px.dtype)
    du = (axis - keypoints_px[..., 0, None]) ** 2  # (..., K, size)
    dv = (axis - keypoints_px[..., 1, None]) ** 2
    return torch.exp(-(dv[..., :, None] + du[..., None, :]) / (2 * sigma_px**2))


def heatmap_2d_loss(maps: torch.Tensor, keypoints_px: torch.Tensor, weights: torch.Tensor,
                    sigma_px: float) -> torch.Tensor:
    """Auxiliary per-view loss of the 2D keypoint head: cross-entropy between softmax(map) over the pixels
    and a normalised Gaussian at the projected keypoint, averaged over the weighted (view, keypoint) pairs.
    (Cross-entropy gives every pixel a gradient from the first step; an L2 loss to sparse 2D peaks stalled
    at all-zero maps for hundreds of steps in our runs.)

    Args:
        maps: (B, C, K, h, h) logits; keypoints_px: (B, C, K, 2) (u, v) in pixels of the map;
        weights: (B, C, K) 1 for a labelled keypoint inside a valid view, else 0.
    """
    target = gaussian_targets_2d(keypoints_px, maps.shape[-1], sigma_px).flatten(3)
    target = target / target.sum(-1, keepdim=True).clamp(min=1e-8)
    per = -(target * torch.log_softmax(maps.flatten(3), dim=-1)).sum(-1)  # (B, C, K)
    return (per * weights).sum() / weights.sum().clamp(min=1)


def peak_normalised(maps: torch.Tensor) -> torch.Tensor:
    """2D logits (..., h, w) -> softmax over the pixels divided by its maximum: (..., h, w) in (0, 1], 1 at
    the most likely pixel."""
    flat = maps.flatten(-2)
    return torch.exp(flat - flat.amax(-1, keepdim=True)).reshape(maps.shape)
