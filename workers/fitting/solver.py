"""Batched Levenberg-Marquardt over frames.

The fitting objective is a sum of squared residuals (`residuals.py`) over few parameters (61 per
frame): Gauss-Newton steps converge in tens of iterations where Adam needs hundreds, and with the
structured normal equations (`Objective.normal_equations`) a step costs about what an Adam step did.
Frames are independent: each has its own damping, acceptance and stopping. Damping follows Nielsen's
gain-ratio rule (K. Madsen, H. B. Nielsen, O. Tingleff, "Methods for non-linear least squares
problems", 2004, section 3.2) with Marquardt's diagonal scaling.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

# (params (B, P), associations) -> (H (B, A, A), g (B, A), cost (B,)) for the active columns.
SystemFn = Callable[[torch.Tensor, object], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]
EvaluateFn = Callable[[torch.Tensor], tuple[torch.Tensor, object]]  # params -> (cost (B,), associations)
MergeFn = Callable[[torch.Tensor, object, object], object]  # (take (B,), new, old) -> associations


@dataclass(frozen=True)
class LMSettings:
    """Attributes:
        iterations: at most this many steps (normal equations) per frame.
        initial_damping: lambda of the first step, relative to the Hessian's diagonal.
        relative_tolerance: a frame stops once an accepted step lowers its cost by less than this fraction.
        max_damping: a frame stops when no step this short lowers its cost.
    """

    iterations: int
    initial_damping: float = 1e-2
    relative_tolerance: float = 1e-4
    min_damping: float = 1e-9
    max_damping: float = 1e8
    extrapolate: bool = True
    reset_damping: bool = True
    extrapolate_ratio: float = 1.2


def levenberg_marquardt(system: SystemFn, evaluate: EvaluateFn, merge: MergeFn, params: torch.Tensor,
                        active: torch.Tensor, settings: LMSettings,
                        tick: Callable[[int], None] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Minimise each frame's cost over the `active` parameter columns.

    Args:
        system: Gauss-Newton system at params with the given (fixed) associations.
        evaluate: the objective's value at params, with its associations (discrete choices) there.
        merge: (take (B,) bool, new, old) -> associations, new where take.
        params: (B, P) start.
        active: (A,) long, the parameter columns optimised (the others stay fixed).
        settings: iteration budget and damping.
        tick: called with the iteration number.
    Returns:
        the optimised params (B, P) and the steps taken per frame (B,) long.
    """
    params = params.detach().clone()
    B = params.shape[0]
    dev = params.device
    cost, assoc = evaluate(params)
    damping = torch.full((B,), settings.initial_damping, dtype=torch.float64, device=dev)
    growth = torch.full((B,), 2.0, dtype=torch.float64, device=dev)
    running = torch.ones(B, dtype=torch.bool, device=dev)
    steps = torch.zeros(B, dtype=torch.int64, device=dev)
    H = g = None
    moved = torch.ones(B, dtype=torch.bool, device=dev)
    for it in range(settings.iterations):
        if not bool(running.any()):
            break
        steps += running
        if H is None or bool(moved.any()):  # a rejected step leaves params, hence H and g, unchanged
            H, g, _ = system(params, assoc)
            H, g = H.double(), g.double()
        diag = torch.diagonal(H, dim1=1, dim2=2)
        D = diag.clamp_min(0) + 1e-9 * diag.amax(1, keepdim=True).clamp_min(1e-30)
        step = -torch.linalg.solve(H + torch.diag_embed(damping[:, None] * D), g[..., None])[..., 0]
        # Predicted decrease of sum(r^2) under the linear model: -(2 g.step + step^T H step).
        predicted = -(2 * (g * step).sum(1) + (step[:, None, :] @ H @ step[..., None])[:, 0, 0])
        trial = params.clone()
        trial[:, active] = params[:, active] + step.to(params.dtype) * running[:, None]
        trial_cost, trial_assoc = evaluate(trial)
        previous = cost
        actual = (cost - trial_cost).double()
        better = running & torch.isfinite(trial_cost) & (actual > 0)
        ratio = actual / predicted.clamp_min(1e-30)
        params = torch.where(better[:, None], trial, params)
        assoc = merge(better, trial_assoc, assoc)
        cost = torch.where(better, trial_cost, cost)
        if settings.extrapolate:
            # The linear model under-predicts when re-associating helps (ratio > 1): try the same step again.
            again = better & (ratio > settings.extrapolate_ratio)
            if bool(again.any()):
                trial = params.clone()
                trial[:, active] = params[:, active] + step.to(params.dtype) * again[:, None]
                trial_cost, trial_assoc = evaluate(trial)
                gained = again & torch.isfinite(trial_cost) & (trial_cost < cost)
                params = torch.where(gained[:, None], trial, params)
                assoc = merge(gained, trial_assoc, assoc)
                cost = torch.where(gained, trial_cost, cost)
        relative = ((previous - cost) / previous.clamp_min(1e-30)).double()
        shrink = torch.clamp(1 - (2 * ratio - 1) ** 3, min=1 / 3)
        # After a rejection the step is shortened at least to the initial damping's length.
        rejected = damping * growth
        if settings.reset_damping:
            rejected = torch.clamp(rejected, min=settings.initial_damping)
        damping = torch.where(better, damping * shrink, rejected)
        damping = damping.clamp(settings.min_damping, settings.max_damping)
        growth = torch.where(better, torch.full_like(growth, 2.0), growth * 2)
        moved = better
        converged = better & (relative < settings.relative_tolerance)
        stalled = ~better & (damping >= settings.max_damping)
        running = running & ~converged & ~stalled
        if tick is not None:
            tick(it)
    return params, steps
