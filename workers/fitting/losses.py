"""The terms of the fitting objective (paper eq. 1-6) as pure torch functions.

Shapes: B frames, C views, K keypoints (21), Vs sampled vertices, N boundary samples, H x W padded
image size. Each returns (B,) so frames fitted in one batch stay independent.
"""

from __future__ import annotations

import torch


def robust_penalty(squared: torch.Tensor, scale: float, kind: str) -> torch.Tensor:
    """Robust version of a squared residual; behaves like `squared` below `scale`.

    geman_mcclure: s^2 r^2 / (s^2 + r^2), bounded by s^2, so one mislabeled click cannot drag the fit.
    huber: r^2 below s, 2 s r - s^2 above (linear growth).
    """
    if kind == "none":
        return squared
    s2 = scale * scale
    if kind == "geman_mcclure":
        return s2 * squared / (s2 + squared)
    if kind == "huber":
        r = squared.clamp_min(1e-12).sqrt()
        return torch.where(r < scale, squared, 2 * scale * r - s2)
    raise ValueError(f"unknown robust penalty {kind!r}")


def weighted_mean(values: torch.Tensor, weights: torch.Tensor, dims: tuple[int, ...]) -> torch.Tensor:
    return (values * weights).sum(dims) / weights.sum(dims).clamp_min(1e-9)


def keypoint_2d_loss(projected_px: torch.Tensor, clicks_px: torch.Tensor, weights: torch.Tensor,
                     px_scale: torch.Tensor, robust: str, robust_scale_px: float) -> torch.Tensor:
    """Click term (eq. 2): projected_px, clicks_px (B, C, K, 2); weights (B, C, K); px_scale (C,)
    converts each view's pixels to reference pixels. Clicks with weight 0 may hold NaN."""
    diff = (projected_px - torch.nan_to_num(clicks_px)) * px_scale[None, :, None, None]
    penalty = robust_penalty((diff * diff).sum(-1), robust_scale_px, robust)
    return weighted_mean(penalty, weights, (1, 2))


def keypoint_3d_loss(keypoints_m: torch.Tensor, targets_m: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """3D keypoint term (eq. 3) in cm^2: keypoints_m, targets_m (B, K, 3); weights (B, K)."""
    diff_cm = 100.0 * (keypoints_m - torch.nan_to_num(targets_m))
    return weighted_mean((diff_cm * diff_cm).sum(-1), weights, (1,))


def sample_image(images: torch.Tensor, points_px: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup: images (B, C, H, W), points_px (B, C, P, 2) as (x, y) -> (B, C, P).

    Pixel centres are integers (docs/conventions.md); outside the canvas the border value is used.
    """
    B, C, H, W = images.shape
    grid = torch.stack([(2 * points_px[..., 0] + 1) / W - 1, (2 * points_px[..., 1] + 1) / H - 1], dim=-1)
    sampled = torch.nn.functional.grid_sample(images.reshape(B * C, 1, H, W), grid.reshape(B * C, 1, -1, 2),
                                              mode="bilinear", padding_mode="border", align_corners=False)
    return sampled.reshape(B, C, -1)


def silhouette_outside_loss(vertices_px: torch.Tensor, outside_dist_px: torch.Tensor, view_weights: torch.Tensor,
                            px_scale: torch.Tensor, cap_px: float | torch.Tensor) -> torch.Tensor:
    """Model pixels far outside the mask (the EDT term of eq. 4), summed over views.

    Every surface point of the model projects inside its silhouette, so each projected vertex is
    penalised by its squared distance to the mask (0 inside), capped at `cap_px` (a number, or (B,) per frame).
    vertices_px (B, C, Vs, 2); outside_dist_px (B, C, H, W); view_weights (B, C); px_scale (C,).
    """
    dist = sample_image(outside_dist_px, vertices_px) * px_scale[None, :, None]
    penalty = robust_penalty(dist * dist, _per_frame(cap_px, 3), "geman_mcclure").mean(-1)  # (B, C)
    return (penalty * view_weights).sum(1)  # summed over views, as eq. 4


def silhouette_coverage_loss(vertices_px: torch.Tensor, boundary_px: torch.Tensor, boundary_valid: torch.Tensor,
                             view_weights: torch.Tensor, px_scale: torch.Tensor, cap_px: float | torch.Tensor,
                             normals: torch.Tensor | None = None, tangent_weight: float = 1.0) -> torch.Tensor:
    """Mask not covered by the model (the ||M - M~|| half of eq. 4), summed over views: each mask boundary
    sample should have a projected model vertex nearby.

    Distances are measured in each sample's boundary frame: along the mask's outward normal, plus
    `tangent_weight` times along the boundary (with `normals` None: plain Euclidean distance). A small
    tangent weight lets the model's sampled vertices slide along the contour: a vertex sample need not
    fall exactly on a boundary sample for it to count as covered.
    vertices_px (B, C, Vs, 2); boundary_px (B, C, N, 2); boundary_valid (B, C, N) bool; view_weights
    (B, C); normals (B, C, N, 2) unit, outward.
    """
    if normals is None:
        frame = torch.eye(2, dtype=vertices_px.dtype, device=vertices_px.device).expand(*boundary_px.shape[:3], 2, 2)
    else:
        tangent = torch.stack([-normals[..., 1], normals[..., 0]], -1)
        frame = torch.stack([normals, tangent_weight * tangent], -2)  # (B, C, N, 2, 2)
    # Components as (frame row) . v - (frame row) . b: two matmuls, no (N, Vs, 2) difference tensor.
    along = (frame @ boundary_px[..., None])[..., 0]  # (B, C, N, 2)
    d2 = 0
    for row in range(2):
        component = frame[..., row, :] @ vertices_px.transpose(-1, -2) - along[..., row, None]  # (B, C, N, Vs)
        d2 = d2 + component * component
    nearest2 = d2.amin(-1) * px_scale[None, :, None] ** 2  # (B, C, N)
    penalty = robust_penalty(nearest2, _per_frame(cap_px, 3), "geman_mcclure")
    per_view = weighted_mean(penalty, boundary_valid.to(penalty.dtype), (2,))
    return (per_view * view_weights).sum(1)  # summed over views, as eq. 4


def _per_frame(value: float | torch.Tensor, dims: int) -> float | torch.Tensor:
    """A number as it is; a (B,) tensor shaped (B, 1, ...) to broadcast against (B, ...) of `dims` dims."""
    return value.reshape(-1, *([1] * (dims - 1))) if torch.is_tensor(value) else value


def shape_prior(betas: torch.Tensor) -> torch.Tensor:
    """(B, 10) -> (B,) sum of squares (eq. 5): stay near MANO's mean shape."""
    return (betas * betas).sum(-1)


def pca_pose_prior(coefficients: torch.Tensor) -> torch.Tensor:
    """(B, k) -> (B,) sum of squared PCA pose coefficients (first half of eq. 6)."""
    return (coefficients * coefficients).sum(-1)


def nearest_pose_prior(articulation: torch.Tensor, bank: torch.Tensor, neighbours: int) -> torch.Tensor:
    """Second half of eq. 6: mean squared distance (rad^2) from articulation (B, 45) to its
    `neighbours` nearest poses in `bank` (N, 45)."""
    d2 = torch.cdist(articulation, bank).square()  # (B, N)
    return d2.topk(min(neighbours, bank.shape[0]), dim=-1, largest=False).values.mean(-1)
