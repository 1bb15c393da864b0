"""The Gauss-Newton normal equations of the fitting objective, without forming its Jacobian.

For the residuals r of `Objective.stacked` and the active parameter columns, returns H = J^T J,
g = J^T r and sum(r^2). A direct Jacobian (a few thousand residuals x 61 parameters, one
forward-mode pass per parameter) costs ~60 ms a step on CPU; this costs a few. Every image residual
depends on one model point in one view, so its derivative with respect to that point is written in
closed form (`differential.py`) and accumulated into one 3x3 block of J^T J (and a 3-vector of
J^T r) per model point; the blocks are then chained with the hand model's point Jacobians
(`FitKinematics.jacobian`). The priors act on the parameters directly. A test checks H and g
against autodiff.
"""

from __future__ import annotations

import torch

from workers.fitting.differential import bilinear_with_gradient, robust_residual_with_jacobian
from workers.fitting.residuals import Associations, Objective, Targets

# Forward-difference step of the hand model's transforms (radians, metres, PCA and shape units), float64.
KINEMATICS_STEP = 1e-6


def normal_equations(objective: Objective, params: torch.Tensor, targets: Targets, assoc: Associations,
                     silhouette: bool, coarse: bool,
                     active: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """H (B, A, A), g (B, A) and cost (B,) at params (B, P) for the `active` (A,) columns, the
    associations held fixed."""
    cfg, w = objective.config, objective.config.weights
    B, P = params.shape
    A = len(active)
    dev, dtype = params.device, params.dtype
    with_vertices = objective.uses_vertices(targets, silhouette, coarse)
    jac = objective.kin.jacobian(params, active, with_vertices, KINEMATICS_STEP)
    geo = jac.geometry
    K = geo.keypoints.shape[1]

    # One projection (with its Jacobian) of the keypoints and the silhouette vertices.
    points = geo.keypoints if not with_vertices else torch.cat([geo.keypoints, geo.silhouette_vertices], 1)
    px, d_px = objective.projector.project_with_jacobian(points)  # (B, C, n, 2), (B, C, n, 2, 3)

    # eq. 2, clicks: per-keypoint 3x3 blocks of J^T J and 3-vectors of J^T r, world coordinates.
    scale = objective.px_scale[None, :, None, None]
    cw = targets.click_weights
    root = (w.kp2d * cw / cw.sum((1, 2), keepdim=True).clamp_min(1e-9)).sqrt()[..., None]  # (B, C, 21, 1)
    e, de = robust_residual_with_jacobian((px[:, :, :K] - targets.clicks) * scale, cfg.robust_scale_px, cfg.robust)
    e = e * root
    rows = (de * (root * scale)[..., None]) @ d_px[:, :, :K]  # (B, C, 21, 2, 3)
    kp_H = (rows.transpose(-1, -2) @ rows).sum(1)  # (B, 21, 3, 3)
    kp_g = (rows.transpose(-1, -2) @ e[..., None])[..., 0].sum(1)  # (B, 21, 3)
    cost = (e * e).sum((1, 2, 3))
    # eq. 3, 3D keypoints (cm^2).
    w3 = objective.kp3d_weight(coarse)
    if w3 > 0:
        kw = targets.keypoint_3d_weights
        share3 = (1e4 * w3 * kw / kw.sum(1, keepdim=True).clamp_min(1e-9))[..., None]  # (B, 21, 1)
        diff3 = geo.keypoints - targets.keypoints_3d
        kp_H = kp_H + share3[..., None] * torch.eye(3, dtype=dtype, device=dev)
        kp_g = kp_g + share3 * diff3
        cost = cost + (share3 * diff3 * diff3).sum((1, 2))
    H = _chain(jac.d_keypoints, kp_H)
    g = torch.einsum("bpia,bpi->ba", jac.d_keypoints, kp_g)

    # eq. 4, silhouettes: per-vertex blocks.
    if with_vertices:
        v_H, v_g, seg_cost = _silhouette_blocks(objective, px[:, :, K:], d_px[:, :, K:], targets, assoc)
        H = H + _chain(jac.d_vertices, v_H)
        g = g + torch.einsum("bpia,bpi->ba", jac.d_vertices, v_g)
        cost = cost + seg_cost

    # eq. 5 and 6: shape and PCA pose priors are linear; the nearest bank poses linear in the coefficients
    # (d articulation / d coefficients = pca^T); joint limits by forward differences of the rotations.
    k = objective.kin.num_pca_comps
    _, _, coefficients, betas = objective.kin.split(params)
    pca = objective.kin.pca  # (k, 45)
    full_H = torch.zeros(P, P, dtype=dtype, device=dev)
    full_g = torch.zeros(B, P, dtype=dtype, device=dev)
    c_cols, b_cols = slice(6, 6 + k), slice(6 + k, P)
    full_H[c_cols, c_cols] = w.pose * torch.eye(k, dtype=dtype, device=dev) + w.nn * pca @ pca.T
    full_H[b_cols, b_cols] = w.shape * torch.eye(P - 6 - k, dtype=dtype, device=dev)
    near = objective.bank[assoc.bank_poses]  # (B, n, 45)
    full_g[:, c_cols] = w.pose * coefficients + w.nn * (geo.articulation - near.mean(1)) @ pca.T
    full_g[:, b_cols] = w.shape * betas
    cost = cost + w.pose * (coefficients * coefficients).sum(1) + w.shape * (betas * betas).sum(1)
    cost = cost + w.nn * ((geo.articulation[:, None] - near) ** 2).sum(-1).mean(1)
    probes = objective.limit_excess(jac.rotation_probes.reshape(-1, 15, 3, 3)).reshape(B, 1 + A, -1)
    excess = probes[:, 0]  # (B, 45)
    d_excess = ((probes[:, 1:] - probes[:, :1]) / jac.step).transpose(1, 2)  # (B, 45, A)
    H = H + full_H[active][:, active] + w.limits * d_excess.transpose(1, 2) @ d_excess
    g = g + full_g[:, active] + w.limits * (d_excess.transpose(1, 2) @ excess[..., None])[..., 0]
    cost = cost + w.limits * (excess * excess).sum(1)
    return H, g, cost


def _silhouette_blocks(objective: Objective, px: torch.Tensor, d_px: torch.Tensor, targets: Targets,
                       assoc: Associations) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The silhouette residuals' per-vertex blocks (B, Vs, 3, 3), J^T r (B, Vs, 3) and cost (B,), from
    the vertices' pixels px (B, C, Vs, 2) and their Jacobians d_px (B, C, Vs, 2, 3)."""
    w = objective.config.weights
    B, C, Vs, _ = px.shape
    views = targets.view_weights
    scale = objective.px_scale[None, :, None]
    # Model outside the mask: e = f(dist), f the capped (Geman-McClure) residual, dist the distance field.
    value, grad = bilinear_with_gradient(targets.outside, targets.height, targets.width, px, targets.outside_rows)
    dist = value * scale
    cap = targets.outside_cap[:, None, None]
    denom = cap * cap + dist * dist
    root = (w.seg * views[..., None] / Vs).sqrt()  # (B, C, 1)
    e_out = dist * cap / denom.sqrt() * root
    slope = root * cap ** 3 / denom ** 1.5 * scale  # d e / d value
    rows = ((slope[..., None] * grad)[..., None, :] @ d_px)[..., 0, :]  # (B, C, Vs, 3)
    v_H = (rows[..., :, None] * rows[..., None, :]).sum(1)
    v_g = (rows * e_out[..., None]).sum(1)
    cost = (e_out * e_out).sum((1, 2))
    # Mask not covered: boundary sample -> its nearest projected vertex, scattered onto that vertex.
    idx = assoc.boundary_vertex  # (B, C, N)
    N = idx.shape[2]
    near_px = torch.gather(px, 2, idx[..., None].expand(B, C, N, 2))
    near_d = torch.gather(d_px, 2, idx[..., None, None].expand(B, C, N, 2, 3))
    bw = targets.boundary_weights
    share = (w.seg * views[..., None] * bw / bw.sum(-1, keepdim=True).clamp_min(1e-9)).sqrt()[..., None]
    frame = objective.boundary_frame(targets)  # (B, C, N, 2, 2)
    d = (frame @ ((near_px - targets.boundary) * scale[..., None])[..., None])[..., 0]
    e, de = robust_residual_with_jacobian(d, targets.coverage_cap[:, None, None, None], "geman_mcclure")
    e = e * share
    rows = (de @ frame * (share * scale[..., None])[..., None]) @ near_d  # (B, C, N, 2, 3)
    blocks = (rows.transpose(-1, -2) @ rows).reshape(B, C * N, 9)
    pulls = (rows.transpose(-1, -2) @ e[..., None]).reshape(B, C * N, 3)
    flat = idx.reshape(B, C * N, 1)
    v_H = v_H + torch.zeros(B, Vs, 9, dtype=px.dtype, device=px.device).scatter_add_(
        1, flat.expand(-1, -1, 9), blocks).reshape(B, Vs, 3, 3)
    v_g = v_g + torch.zeros(B, Vs, 3, dtype=px.dtype, device=px.device).scatter_add_(1, flat.expand(-1, -1, 3), pulls)
    return v_H, v_g, cost + (e * e).sum((1, 2, 3))


def _chain(d_points: torch.Tensor, blocks: torch.Tensor) -> torch.Tensor:
    """sum over points of D_p^T M_p D_p: d_points (B, N, 3, A), blocks (B, N, 3, 3) -> (B, A, A)."""
    B, N, _, A = d_points.shape
    weighted = blocks @ d_points  # (B, N, 3, A)
    return d_points.reshape(B, N * 3, A).transpose(1, 2) @ weighted.reshape(B, N * 3, A)
