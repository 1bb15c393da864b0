"""Sparsification curves (Ilg et al. 2018; FreiHAND supplementary, Fig. "sparse_error").

Remove the least confident predictions step by step and report the mean error of the rest; the oracle
removes the largest errors first. AUSE = area between the two curves over the removed fraction [0, 1)
(same unit as the error; smaller = the confidence ranks errors better).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Sparsification:
    """fractions (S,) removed fraction in [0, 1); curve / oracle (S,) mean error of the remaining samples;
    ause: area between curve and oracle; auc: area under the curve (unit of the error)."""

    fractions: np.ndarray
    curve: np.ndarray
    oracle: np.ndarray
    ause: float
    auc: float


def _remaining_mean(errors_sorted_worst_first: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    n = len(errors_sorted_worst_first)
    out = np.empty(len(fractions))
    for i, f in enumerate(fractions):
        removed = min(int(np.floor(f * n)), n - 1)
        out[i] = errors_sorted_worst_first[removed:].mean()
    return out


def sparsification(errors: np.ndarray, confidence: np.ndarray, steps: int = 50) -> Sparsification:
    """Curves for per-sample errors (N,) and confidences (N,) (higher = more confident)."""
    errors, confidence = np.asarray(errors, float), np.asarray(confidence, float)
    if errors.ndim != 1 or errors.shape != confidence.shape or len(errors) == 0:
        raise ValueError(f"errors and confidence must be equal non-empty (N,) arrays, got {errors.shape}, "
                         f"{confidence.shape}")
    fractions = np.arange(steps) / steps
    by_conf = errors[np.argsort(confidence, kind="stable")]  # least confident first
    by_err = np.sort(errors)[::-1]  # largest error first
    curve, oracle = _remaining_mean(by_conf, fractions), _remaining_mean(by_err, fractions)
    width = 1.0 / steps
    return Sparsification(fractions, curve, oracle, float(np.sum(curve - oracle) * width),
                          float(np.sum(curve) * width))


def plot_sparsification(curves: dict[str, Sparsification], path: Path | str, unit: str = "mm") -> Path:
    """Write a PNG: each curve (solid) with its oracle (dashed), as in the supplementary figure."""
    import matplotlib  # deferred: the API's dashboard uses the curves (numpy) and never plots

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for (name, s), color in zip(curves.items(), ("tab:blue", "tab:orange", "tab:green", "tab:red"), strict=False):
        ax.plot(s.fractions, s.curve, color=color, label=f"{name} (AUSE {s.ause:.2f} {unit})")
        ax.plot(s.fractions, s.oracle, color=color, linestyle="--", label=f"{name} oracle")
    ax.set_xlabel("fraction of samples removed (least confident first)")
    ax.set_ylabel(f"mean 3D keypoint error of the rest ({unit})")
    ax.set_xlim(0, 1)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
