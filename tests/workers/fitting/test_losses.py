"""Each loss term: a gradient check, and a case where it alone moves the fit the right way."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from workers.fitting import losses


def _double(*shape, seed=0):
    return torch.randn(*shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


@pytest.mark.parametrize("kind", ["none", "geman_mcclure", "huber"])
def test_robust_penalty_gradcheck_and_shape(kind):
    x = (_double(12).abs() * 10).requires_grad_()
    assert torch.autograd.gradcheck(lambda v: losses.robust_penalty(v, 3.0, kind), (x,))
    small = torch.tensor([0.01], dtype=torch.float64)
    assert torch.allclose(losses.robust_penalty(small, 3.0, kind), small, rtol=0.01)


def test_geman_mcclure_is_bounded():
    huge = torch.tensor([1e6], dtype=torch.float64)
    assert losses.robust_penalty(huge, 5.0, "geman_mcclure") < 25.0
    assert losses.robust_penalty(huge, 5.0, "huber") < huge


def test_keypoint_2d_gradcheck_and_nan_clicks_ignored():
    proj = _double(2, 3, 21, 2).requires_grad_()
    clicks = _double(2, 3, 21, 2, seed=1)
    weights = (torch.rand(2, 3, 21, dtype=torch.float64) > 0.5).double()
    clicks[weights == 0] = float("nan")
    scale = torch.ones(3, dtype=torch.float64)

    def f(p):
        return losses.keypoint_2d_loss(p, clicks, weights, scale, "geman_mcclure", 2.0)

    assert torch.isfinite(f(proj)).all()
    assert torch.autograd.gradcheck(f, (proj,))


def test_keypoint_2d_alone_pulls_projection_onto_clicks():
    proj = torch.zeros(1, 2, 21, 2, dtype=torch.float64, requires_grad=True)
    clicks = torch.full((1, 2, 21, 2), 4.0, dtype=torch.float64)
    weights = torch.ones(1, 2, 21, dtype=torch.float64)
    opt = torch.optim.Adam([proj], lr=0.2)
    for _ in range(200):
        opt.zero_grad()
        scale = torch.ones(2, dtype=torch.float64)
        losses.keypoint_2d_loss(proj, clicks, weights, scale, "huber", 2.0).sum().backward()
        opt.step()
    assert (proj - clicks).abs().max() < 0.05


def test_keypoint_3d_in_square_centimetres():
    kp = torch.zeros(1, 21, 3, dtype=torch.float64)
    target = kp.clone()
    target[0, :, 0] = 0.01  # 1 cm
    assert torch.allclose(losses.keypoint_3d_loss(kp, target, torch.ones(1, 21, dtype=torch.float64)),
                          torch.tensor([1.0], dtype=torch.float64))


def test_sample_image_uses_pixel_centres():
    image = torch.arange(12, dtype=torch.float64).reshape(1, 1, 3, 4)
    points = torch.tensor([[[[0.0, 0.0], [3.0, 2.0], [1.5, 1.0]]]], dtype=torch.float64)
    values = losses.sample_image(image, points)
    assert torch.allclose(values, torch.tensor([[[0.0, 11.0, 5.5]]], dtype=torch.float64))


def _square_mask(size=40, lo=10, hi=30):
    mask = np.zeros((size, size), dtype=bool)
    mask[lo:hi, lo:hi] = True
    return mask


def test_silhouette_outside_alone_pulls_points_into_the_mask():
    from workers.fitting.masks import outside_distance_px

    dist = torch.as_tensor(outside_distance_px(_square_mask()), dtype=torch.float64)[None, None]
    pts = torch.tensor([[[[2.0, 2.0], [37.0, 20.0], [20.0, 20.0]]]], dtype=torch.float64, requires_grad=True)
    ones = torch.ones(1, 1, dtype=torch.float64)
    scale = torch.ones(1, dtype=torch.float64)
    assert torch.autograd.gradcheck(
        lambda p: losses.silhouette_outside_loss(p + 0.3, dist, ones, scale, 25.0), (pts,))
    opt = torch.optim.Adam([pts], lr=0.5)
    for _ in range(150):
        opt.zero_grad()
        losses.silhouette_outside_loss(pts, dist, ones, scale, 25.0).sum().backward()
        opt.step()
    inside = (pts[0, 0] >= 9.5) & (pts[0, 0] <= 29.5)
    assert inside.all(), pts


def test_silhouette_coverage_alone_spreads_points_to_the_boundary():
    from workers.fitting.masks import boundary_points

    boundary = boundary_points(_square_mask(), 64, np.random.default_rng(0))
    b = torch.as_tensor(boundary, dtype=torch.float64)[None, None]
    valid = torch.ones(1, 1, len(boundary), dtype=torch.bool)
    ones = torch.ones(1, 1, dtype=torch.float64)
    scale = torch.ones(1, dtype=torch.float64)
    pts = (20 + torch.randn(1, 1, 32, 2, dtype=torch.float64)).requires_grad_()
    before = losses.silhouette_coverage_loss(pts, b, valid, ones, scale, 25.0).item()
    opt = torch.optim.Adam([pts], lr=0.3)
    for _ in range(300):
        opt.zero_grad()
        losses.silhouette_coverage_loss(pts, b, valid, ones, scale, 25.0).sum().backward()
        opt.step()
    after = losses.silhouette_coverage_loss(pts, b, valid, ones, scale, 25.0).item()
    assert after < 0.2 * before
    spread = pts[0, 0].detach().numpy()
    assert spread[:, 0].max() - spread[:, 0].min() > 15  # the points moved out toward the edges


def test_priors_pull_toward_their_centres():
    betas = _double(2, 10).requires_grad_()
    losses.shape_prior(betas).sum().backward()
    assert (torch.sign(betas.grad) == torch.sign(betas)).all()
    bank = _double(50, 45, seed=3)
    pose = (bank[7] + 0.01 * _double(45, seed=4))[None].requires_grad_()
    losses.nearest_pose_prior(pose, bank, 1).sum().backward()
    stepped = pose - 0.1 * pose.grad
    assert (stepped - bank[7]).norm() < (pose - bank[7]).norm()
