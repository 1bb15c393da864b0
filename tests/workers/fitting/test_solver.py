"""Batched Levenberg-Marquardt: converges on a non-linear least-squares problem, frame by frame."""

from __future__ import annotations

import torch

from workers.fitting.solver import LMSettings, levenberg_marquardt


def _rosenbrock(params: torch.Tensor) -> torch.Tensor:
    """Residuals (B, 2) of the Rosenbrock function per row: minimum 0 at (1, 1), a curved narrow valley."""
    x, y = params[:, 0], params[:, 1]
    return torch.stack([1 - x, 10 * (y - x * x)], 1)


def _system(params: torch.Tensor, assoc, active: torch.Tensor):
    x = params[:, 0]
    r = _rosenbrock(params)
    J = torch.zeros(len(params), 2, 2, dtype=params.dtype)
    J[:, 0, 0] = -1
    J[:, 1, 0] = -20 * x
    J[:, 1, 1] = 10
    J = J[..., active]
    return J.transpose(1, 2) @ J, (J.transpose(1, 2) @ r[..., None])[..., 0], (r * r).sum(1)


def test_converges_per_frame_and_keeps_inactive_columns():
    start = torch.tensor([[-1.2, 1.0, 5.0], [2.0, -1.0, 7.0], [1.0, 1.0, 3.0]], dtype=torch.float64)
    active = torch.tensor([0, 1])
    solved, steps = levenberg_marquardt(
        lambda p, a: _system(p, a, active), lambda p: ((_rosenbrock(p) ** 2).sum(1), None), lambda t, n, o: n,
        start, active, LMSettings(iterations=100, relative_tolerance=1e-12))
    assert torch.allclose(solved[:, :2], torch.ones(3, 2, dtype=torch.float64), atol=1e-5)
    assert torch.equal(solved[:, 2], start[:, 2])  # not an active column
    assert steps[2] < steps[0]  # the frame that starts at the minimum stops at once
    assert int(steps.max()) < 100


def test_only_active_columns_move():
    start = torch.tensor([[-1.2, 3.0]], dtype=torch.float64)
    active = torch.tensor([0])  # y fixed at 3: a 1D problem over x
    solved, _ = levenberg_marquardt(
        lambda p, a: _system(p, a, active), lambda p: ((_rosenbrock(p) ** 2).sum(1), None), lambda t, n, o: n,
        start, active, LMSettings(iterations=100, relative_tolerance=1e-12))
    assert solved[0, 1] == 3.0
    x = solved[0, 0]
    gradient = -2 * (1 - x) - 400 * x * (3 - x * x)  # d/dx of (1 - x)^2 + 100 (y - x^2)^2
    assert abs(float(gradient)) < 1e-6 and 1.6 < abs(float(x)) < 1.8  # a stationary point of the 1D problem
