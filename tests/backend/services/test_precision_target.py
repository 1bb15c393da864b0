"""The precision target (issue 40, services.review.precision_target): the loosest scale of the paper's thresholds whose
judged labels' Wilson upper bound meets the target; the paper's until enough audits exist."""

from __future__ import annotations

import pytest

from backend.services.review.precision_target import Evidence, choose, passes, scaled
from backend.services.review.verification import HeuristicThresholds, heuristic_verdict

PAPER = HeuristicThresholds()


def _label(confidence: float, wrong: bool, source: str = "audit", distance_m: float = 0.002) -> Evidence:
    return Evidence({"mean_confidence": confidence, "min_confidence": confidence, "mean_iou": 0.9,
                     "low_iou_views": 0.0, "mean_distance_m": distance_m, "max_distance_m": distance_m}, wrong, source)


def test_scale_one_is_the_paper_and_passes_agrees_with_the_heuristic():
    assert scaled(PAPER, 1.0) == PAPER
    loose = scaled(PAPER, 2.0)
    assert loose.min_mean_confidence == pytest.approx(0.6) and loose.max_mean_distance_m == pytest.approx(0.010)
    for confidence in (0.55, 0.7, 0.85, 0.95):
        verdict = heuristic_verdict([confidence] * 21, [0.9] * 4, [[0, 0, 0]] * 21, [[0.002, 0, 0]] * 21, PAPER)
        assert passes(verdict.metrics, PAPER) == verdict.accepted
    with pytest.raises(ValueError, match="scale"):
        scaled(PAPER, 0)


def test_paper_thresholds_without_a_target_or_before_enough_audits():
    items = [_label(0.9, False) for _ in range(10)]
    assert choose(items, PAPER, None, 5).chosen_by == "paper"
    few = choose(items, PAPER, 0.02, 30)
    assert few.chosen_by == "paper" and few.thresholds == PAPER and "until 30 labels are audited: 10" in few.explanation


def test_the_loosest_scale_that_meets_the_target_with_the_upper_bound():
    # 400 right labels at confidence 0.9 (accepted by the paper's), 300 right at 0.75 (needs scale >= 1.25), and at
    # 0.66 (scale >= 1.75) as many wrong as right: loosening to 1.5 keeps the upper bound under 2 %, 1.75 does not.
    items = ([_label(0.9, False) for _ in range(400)] + [_label(0.75, False, "review") for _ in range(300)]
             + [_label(0.66, i % 2 == 0, "review") for i in range(100)])
    choice = choose(items, PAPER, 0.02, 30)
    assert choice.chosen_by == "target" and choice.scale == 1.5
    assert choice.evidence_labels == 700 and choice.evidence_wrong == 0 and choice.upper_bound <= 0.02
    assert "1.5x the paper's thresholds" in choice.explanation


def test_no_scale_qualifies_keeps_the_paper_and_says_why():
    items = [_label(0.9, i % 10 == 0) for i in range(100)]  # 10 % wrong even at the strictest
    choice = choose(items, PAPER, 0.02, 30)
    assert choice.chosen_by == "paper" and "the paper's thresholds stay" in choice.explanation
    assert "10 of 100 wrong" in choice.explanation
