"""The residual form of the objective equals the loss functions, and its normal equations equal J^T J, J^T r."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from torch.func import jacfwd

from workers.fitting import differential, losses
from workers.fitting.config import FitConfig
from workers.fitting.engine import FittingEngine
from workers.fitting.gauss_newton import normal_equations
from workers.fitting.residuals import Targets, bilinear_lookup, robust_residual
from workers.geometry.projection import project_points_torch, stack_cameras


def _setup(hand, rig, frames, config: FitConfig, kp3d=None):
    """Engine, float64 targets (with silhouettes) and perturbed start vectors for the given frames; the
    first frame's masks are treated as foreground masks (cut at the wrist, their own caps)."""
    engine = FittingEngine(hand, rig, config)
    frames = [dataclasses.replace(frames[0], masks_include_forearm=True), *frames[1:]]
    if kp3d is not None:
        frames = [dataclasses.replace(f, keypoints_3d=kp3d + 0.004) for f in frames]
    start = engine._start_vectors(engine._placements(frames), 1)
    start[:, 6:] += 0.05 * torch.randn(start[:, 6:].shape, generator=torch.Generator().manual_seed(0),
                                       dtype=torch.float64)
    with torch.no_grad():
        out = engine._forward(engine._params(start))
    silhouettes = engine._prepare_silhouettes(frames, out.joints.double().numpy(), out.vertices.double().numpy())
    clicks = engine._tensor(np.stack([np.nan_to_num(f.clicks_px) for f in frames]))
    weights = engine._tensor(np.stack([f.click_weights for f in frames]))
    targets = engine._with_silhouettes(Targets(clicks, weights, *engine._targets_3d(frames)), silhouettes)
    return engine, targets.to(torch.float64), silhouettes, start


@pytest.mark.parametrize("robust", ["geman_mcclure", "huber", "none"])
def test_residual_terms_equal_the_loss_functions(hand, rig, known_frames, robust):
    frames, truth = known_frames
    config = FitConfig(robust=robust).with_weights(kp3d=1000.0)
    engine, targets, silhouettes, start = _setup(hand, rig, frames, config, kp3d=truth["keypoints"][0])
    residual_terms = engine.objective.terms(start, targets, silhouette=True)
    engine64 = FittingEngine(hand, rig, config, dtype=torch.float64)
    params = engine64._params(start)
    sil64 = {k: (v.double() if torch.is_tensor(v) and v.is_floating_point() else v) for k, v in silhouettes.items()}
    loss_terms = engine64._loss_terms(params, targets.clicks, targets.click_weights, targets.keypoints_3d,
                                      targets.keypoint_3d_weights, sil64)
    assert set(loss_terms) == set(residual_terms)
    for name, value in loss_terms.items():
        assert torch.allclose(residual_terms[name], value, rtol=1e-9, atol=1e-9), name
    assert float(residual_terms["seg"].min()) > 0 and float(residual_terms["kp2d"].min()) > 0
    assert targets.outside_cap.tolist() == [config.silhouette_cap_px, config.hand_mask_silhouette_cap_px]


@pytest.mark.parametrize(("robust", "coarse", "tangent_weight"),
                         [("geman_mcclure", False, 0.3), ("huber", False, 1.0), ("none", True, 0.3)])
def test_normal_equations_match_autodiff(hand, rig, known_frames, robust, coarse, tangent_weight):
    frames, truth = known_frames
    # Fewer samples than the defaults keep the reference Jacobian (forward-mode autodiff) quick.
    config = FitConfig(robust=robust, coverage_tangent_weight=tangent_weight, silhouette_vertices=96,
                       boundary_points=32).with_weights(kp3d=1000.0)
    engine, targets, _, start = _setup(hand, rig, frames, config, kp3d=truth["keypoints"][1])
    objective = engine.objective
    silhouette = not coarse
    active = engine._columns(engine._STAGE1 if coarse else engine._STAGE2)
    assoc = objective.associate(start, targets, silhouette, coarse)
    H, g, cost = normal_equations(objective, start, targets, assoc, silhouette, coarse, active)

    def residuals(p):
        return objective.stacked(p, targets, assoc, silhouette, coarse)

    r = residuals(start)
    full = jacfwd(residuals)(start)  # (B, R, B, P)
    J = torch.stack([full[b, :, b][:, active] for b in range(len(start))])
    assert torch.allclose(cost, (r * r).sum(1), rtol=1e-12)
    assert torch.allclose(cost, objective.evaluate(start, targets, silhouette, coarse)[0], rtol=1e-12)
    H_ref, g_ref = J.transpose(1, 2) @ J, (J.transpose(1, 2) @ r[..., None])[..., 0]
    assert torch.allclose(H, H_ref, rtol=0, atol=1e-6 * H_ref.abs().max())
    assert torch.allclose(g, g_ref, rtol=0, atol=1e-6 * g_ref.abs().max())


def test_projection_jacobian_matches_autograd(rig):
    cams = stack_cameras(rig, torch.float64)
    cams["dist"] = cams["dist"] + torch.tensor([0.05, -0.02, 0.003, -0.002, 0.01], dtype=torch.float64)
    points = (0.1 * torch.randn(1, 7, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64))
    pixels, jac = differential.project_with_jacobian(points, **cams)
    reference, _ = project_points_torch(points, **cams)
    assert torch.allclose(pixels, reference)
    full = torch.autograd.functional.jacobian(lambda p: project_points_torch(p, **cams)[0], points)  # (1,C,N,2,1,N,3)
    diagonal = torch.stack([full[0, :, n, :, 0, n] for n in range(points.shape[1])], 1)  # (C, N, 2, 3)
    assert torch.allclose(jac[0], diagonal, atol=1e-9)


def test_bilinear_lookup_and_gradient_match_grid_sample():
    image = torch.rand(1, 2, 9, 11, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    points = torch.tensor([[[[0.0, 0.0], [3.3, 4.7], [10.0, 8.0], [-2.0, 3.5], [12.5, 9.5], [5.5, 2.25]]] * 2],
                          dtype=torch.float64, requires_grad=True)
    flat = image.reshape(1, 2, -1)
    reference = losses.sample_image(image, points)
    value, grad = differential.bilinear_with_gradient(flat, 9, 11, points.detach())
    assert torch.allclose(bilinear_lookup(flat, 9, 11, points), reference)
    assert torch.allclose(value, reference)
    (ref_grad,) = torch.autograd.grad(reference.sum(), points)
    interior = torch.tensor([True, True, False, False, False, True])  # grid_sample's gradient at a clamped border
    assert torch.allclose(grad[..., interior, :], ref_grad[..., interior, :])
    assert torch.all(grad[0, 0, 3, 0] == 0) and torch.all(grad[0, 0, 4] == 0)  # beyond the border: no pull


@pytest.mark.parametrize("kind", ["geman_mcclure", "huber", "none"])
def test_robust_residual_squares_to_the_penalty_and_has_the_right_jacobian(kind):
    diff = torch.tensor([[0.3, -0.2], [4.0, 1.0], [-30.0, 12.0], [1e-4, 0.0]], dtype=torch.float64)
    e = robust_residual(diff, 3.0, kind)
    assert torch.allclose((e * e).sum(-1), losses.robust_penalty((diff * diff).sum(-1), 3.0, kind))
    value, jac = differential.robust_residual_with_jacobian(diff, 3.0, kind)
    assert torch.allclose(value, e)
    for i in range(len(diff)):
        reference = torch.autograd.functional.jacobian(lambda d: robust_residual(d[None], 3.0, kind)[0], diff[i])
        assert torch.allclose(jac[i], reference, atol=1e-9), (kind, i)
