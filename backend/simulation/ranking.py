"""How well the review queue's ranks order a round's fits by their true error (simulation only: it needs the truth).

The review policy keeps the candidates from a score's median up (`select_for_review`); a rank helps the reviewers
when the fits it puts first are the good ones. Per rank (backend.services.review.verification.REVIEW_RANKS) two
figures over the round's fits from predictions the heuristic did not accept:
- `spearman`: Spearman's correlation of the score with minus the fit's true vertex error (+1: best-first exactly,
  0: no better than chance, negative: the worst first);
- `upper_half_good_share`: of the fits from the score's median up (the fixed policy's cut), the share the simulated
  reviewers would accept (true error under their limit), beside `good_share` over all of them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.stats import spearmanr

MIN_FITS = 3  # Spearman's correlation of fewer is not worth a figure


def _varies(values: np.ndarray) -> bool:
    """More than rounding noise apart (a rank of float noise is no rank)."""
    return bool(np.ptp(values) > 1e-9 * max(1.0, float(np.abs(values).max())))


def rank_quality(errors_mm: Sequence[float], scores: Mapping[str, Sequence[float | None]],
                 good_below_mm: float) -> dict[str, Any]:
    """The ranks' quality over one round's candidate fits.

    Args:
        errors_mm: (F,) each fit's true mean vertex error, millimetres.
        scores: rank name -> (F,) the score it ranks the fits by, higher first; None where the fit has none (those
            fits are left out of that rank's figures).
        good_below_mm: the reviewers' accept limit (a fit under it is one they would accept).

    Returns:
        {"fits", "good_below_mm", "good_share", "by_rank": {rank: {"scored", "spearman", "upper_half_good_share"}}};
        None for a figure over fewer than MIN_FITS fits (or with a constant score or error).
    """
    errors = np.asarray(errors_mm, dtype=np.float64)
    if errors.ndim != 1 or not np.isfinite(errors).all():
        raise ValueError(f"errors_mm must be (F,) finite millimetres, got shape {errors.shape}")
    good = errors < good_below_mm
    by_rank: dict[str, dict[str, Any]] = {}
    for rank, values in scores.items():
        if len(values) != len(errors):
            raise ValueError(f"rank {rank!r}: {len(values)} scores for {len(errors)} fits")
        known = np.array([v is not None and np.isfinite(v) for v in values], dtype=bool)
        score = np.array([v for v, k in zip(values, known, strict=True) if k], dtype=np.float64)
        err, ok = errors[known], good[known]
        figures: dict[str, Any] = {"scored": int(known.sum()), "spearman": None, "upper_half_good_share": None}
        if len(score) >= MIN_FITS:
            upper = score >= np.percentile(score, 50.0)  # as select_for_review's percentile cut
            figures["upper_half_good_share"] = float(ok[upper].mean())
            if _varies(score) and _varies(err):
                figures["spearman"] = float(spearmanr(score, -err).statistic)
        by_rank[rank] = figures
    return {"fits": len(errors), "good_below_mm": float(good_below_mm),
            "good_share": float(good.mean()) if len(errors) else None, "by_rank": by_rank}
