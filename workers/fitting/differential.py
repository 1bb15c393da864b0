"""Values together with their derivatives, for the Gauss-Newton normal equations of `residuals.py`.

Every residual of the objective that involves the image depends on one model point in one view.
Knowing d(residual)/d(point) in closed form lets the solver accumulate a 3x3 block per model point
(`residuals.Objective.normal_equations`) instead of forming a (residuals x parameters) Jacobian: the
per-view work then never carries the parameter dimension. Tests compare each function here with
autograd on its value-only twin (`project_points_torch`, `losses.sample_image`, `robust_residual`).
"""

from __future__ import annotations

import torch


class RigProjector:
    """Projection into every view of a rig (the same pixels as `project_points_torch`), with few operations.

    Per-camera constants are prepared once; lens terms that are zero for the whole rig (tangential
    distortion, k3, usually) are skipped. A fit projects hundreds of points per step, so the cost is
    the number of tensor operations, not arithmetic.

    Args:
        K, dist, R, t: (C,3,3), (C,5), (C,3,3), (C,3) from `stack_cameras`.
        min_depth_m: depths below this are clamped before division, as in `project_points_torch`.
    """

    def __init__(self, K: torch.Tensor, dist: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
                 min_depth_m: float = 1e-4) -> None:
        self.R, self.t = R, t[:, None, :]  # (C, 3, 3), (C, 1, 3)
        self.intrinsics = K[:, :2, :2]  # (C, 2, 2): [[fx, skew], [0, fy]]
        self.centre = K[:, None, :2, 2]  # (C, 1, 2)
        self.k1, self.k2, self.k3 = (dist[:, i, None, None] for i in (0, 1, 4))  # (C, 1, 1)
        self.p = dist[:, None, 2:4]  # (C, 1, 2): p1, p2
        self.tangential = bool(torch.any(dist[:, 2:4] != 0))
        self.cubic = bool(torch.any(dist[:, 4] != 0))
        self.min_depth_m = min_depth_m

    def _normalised(self, points_world: torch.Tensor):
        cam = torch.einsum("cij,bnj->bcni", self.R, points_world) + self.t  # (B, C, N, 3)
        depth = cam[..., 2:]
        z = depth.clamp(min=self.min_depth_m)
        return cam, depth, z, cam[..., :2] / z

    def _distort(self, xy: torch.Tensor):
        """Distorted normalised coordinates, r^2 and the radial factor of xy (B, C, N, 2)."""
        r2 = (xy * xy).sum(-1, keepdim=True)
        poly = self.k2 + r2 * self.k3 if self.cubic else self.k2
        radial = 1 + r2 * (self.k1 + r2 * poly)
        distorted = xy * radial
        if self.tangential:
            x, y = xy[..., :1], xy[..., 1:]
            p_swapped = self.p.flip(-1)  # (p2, p1)
            distorted = distorted + 2 * x * y * self.p + (r2 + 2 * xy * xy) * p_swapped
        return distorted, r2, radial

    def project(self, points_world: torch.Tensor) -> torch.Tensor:
        """points (B, N, 3) metres -> pixels (B, C, N, 2)."""
        _, _, _, xy = self._normalised(points_world)
        distorted, _, _ = self._distort(xy)
        return torch.einsum("cij,bcnj->bcni", self.intrinsics, distorted) + self.centre

    def project_with_jacobian(self, points_world: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points (B, N, 3) metres -> pixels (B, C, N, 2) and d(pixel)/d(point) (B, C, N, 2, 3), px/m."""
        _, depth, z, xy = self._normalised(points_world)
        distorted, r2, radial = self._distort(xy)
        pixels = torch.einsum("cij,bcnj->bcni", self.intrinsics, distorted) + self.centre
        # d distorted / d xy = radial I + 2 radial'(r2) xy xy^T (+ tangential terms).
        poly = 2 * self.k2 + 3 * r2 * self.k3 if self.cubic else 2 * self.k2
        d_radial = self.k1 + r2 * poly  # d radial / d r2
        outer = xy[..., :, None] * xy[..., None, :]  # (B, C, N, 2, 2)
        eye = torch.eye(2, dtype=xy.dtype, device=xy.device)
        D = radial[..., None] * eye + (2 * d_radial)[..., None] * outer
        if self.tangential:
            x, y = xy[..., 0], xy[..., 1]
            p1, p2 = self.p[..., 0], self.p[..., 1]
            off = 2 * p1 * x + 2 * p2 * y
            D = D + torch.stack([torch.stack([2 * p1 * y + 6 * p2 * x, off], -1),
                                 torch.stack([off, 6 * p1 * y + 2 * p2 * x], -1)], -2)
        AD = torch.einsum("cij,bcnjk->bcnik", self.intrinsics, D)  # (B, C, N, 2, 2) d pixel / d xy
        # d xy / d camera point = [I / z | -xy / z] (no depth derivative where the depth is clamped).
        live = (depth > self.min_depth_m).to(z.dtype)
        d_depth = -(AD @ xy[..., None]) * (live / z)[..., None]  # (B, C, N, 2, 1)
        d_cam = torch.cat([AD / z[..., None], d_depth], -1)  # (B, C, N, 2, 3)
        return pixels, torch.einsum("bcnij,cjk->bcnik", d_cam, self.R)


def project_with_jacobian(points_world: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, R: torch.Tensor,
                          t: torch.Tensor, min_depth_m: float = 1e-4) -> tuple[torch.Tensor, torch.Tensor]:
    """`project_points_torch` plus d(pixel)/d(world point): points (B, N, 3) metres -> pixels (B, C, N, 2)
    and jacobian (B, C, N, 2, 3) in pixels per metre (see `RigProjector`)."""
    return RigProjector(K, dist, R, t, min_depth_m).project_with_jacobian(points_world)


def image_corners(images: torch.Tensor, height: int, width: int, x: torch.Tensor, y: torch.Tensor,
                  rows: torch.Tensor | None) -> torch.Tensor:
    """The 4 pixels around (x, y) (clamped, (B, C, N) each): (B, C, N, 4) values of images (F, C, H * W),
    frame b reading row rows[b] (None: row b): top-left, top-right, bottom-left, bottom-right."""
    B, C = x.shape[:2]
    rows = torch.arange(B, device=x.device) if rows is None else rows
    image = (rows[:, None] * C + torch.arange(C, device=x.device)) * (height * width)  # (B, C) first pixels
    base = (y * width + x).long() + image[..., None]
    corners = torch.stack([base, base + 1, base + width, base + width + 1], -1)  # (B, C, N, 4)
    return images.reshape(-1)[corners]


def bilinear_with_gradient(images: torch.Tensor, height: int, width: int, points_px: torch.Tensor,
                           rows: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """`residuals.bilinear_lookup` plus its gradient in the point.

    images (F, C, H * W) flattened, points_px (B, C, N, 2) as (x, y), rows (B,) the image row of each
    frame (None: row b) -> values (B, C, N) and gradients (B, C, N, 2) (zero where the point lies
    beyond the border, which is clamped).
    """

    x_raw, y_raw = points_px[..., 0], points_px[..., 1]
    x = x_raw.clamp(0, width - 1)
    y = y_raw.clamp(0, height - 1)
    x0 = x.floor().clamp(max=max(width - 2, 0))
    y0 = y.floor().clamp(max=max(height - 2, 0))
    fx, fy = x - x0, y - y0
    v00, v01, v10, v11 = image_corners(images, height, width, x0, y0, rows).unbind(-1)
    value = (1 - fx) * (1 - fy) * v00 + fx * (1 - fy) * v01 + (1 - fx) * fy * v10 + fx * fy * v11
    inside_x = ((x_raw >= 0) & (x_raw <= width - 1)).to(value.dtype)
    inside_y = ((y_raw >= 0) & (y_raw <= height - 1)).to(value.dtype)
    gx = ((1 - fy) * (v01 - v00) + fy * (v11 - v10)) * inside_x
    gy = ((1 - fx) * (v10 - v00) + fx * (v11 - v01)) * inside_y
    return value, torch.stack([gx, gy], -1)


def robust_residual_with_jacobian(diff: torch.Tensor, scale: float | torch.Tensor,
                                  kind: str) -> tuple[torch.Tensor, torch.Tensor]:
    """`residuals.robust_residual` e(d) = d phi(|d|) plus de/dd: diff (..., D) -> (..., D), (..., D, D)."""
    D = diff.shape[-1]
    eye = torch.eye(D, dtype=diff.dtype, device=diff.device)
    if kind == "none":
        return diff, eye.expand(*diff.shape, D)
    squared = (diff * diff).sum(-1, keepdim=True)
    outer = diff[..., :, None] * diff[..., None, :]
    if kind == "geman_mcclure":
        # phi = s / sqrt(s^2 + q): de/dd = phi I - s (s^2 + q)^(-3/2) d d^T
        denom = scale * scale + squared
        phi = scale / torch.sqrt(denom)
        return diff * phi, phi[..., None] * eye - (phi / denom)[..., None] * outer
    if kind == "huber":
        r = squared.clamp_min(1e-12).sqrt()
        root = torch.sqrt((2 * scale * r - scale * scale).clamp_min(1e-12))
        above = r >= scale
        phi = torch.where(above, root / r, torch.ones_like(r))
        # d phi / d r above the scale: (s / root - root / r) / r; d phi / d d = (d phi / d r) d / r
        dphi_dr = torch.where(above, (scale / root - root / r) / r, torch.zeros_like(r))
        return diff * phi, phi[..., None] * eye + (dphi_dr / r)[..., None] * outer
    raise ValueError(f"unknown robust penalty {kind!r}")
