"""The review ranks' quality figure of the simulation (backend.simulation.ranking)."""

import pytest

from backend.simulation.ranking import rank_quality

ERRORS = [2.0, 4.0, 6.0, 9.0, 12.0, 20.0]  # mm; three under the 8 mm limit


def test_a_rank_that_puts_the_good_fits_first_scores_one_and_the_reverse_minus_one():
    figures = rank_quality(ERRORS, {"best": [-e for e in ERRORS], "worst": list(ERRORS)}, good_below_mm=8.0)
    assert figures["fits"] == 6 and figures["good_share"] == 0.5 and figures["good_below_mm"] == 8.0
    assert figures["by_rank"]["best"] == {"scored": 6, "spearman": pytest.approx(1.0), "upper_half_good_share": 1.0}
    assert figures["by_rank"]["worst"] == {"scored": 6, "spearman": pytest.approx(-1.0),
                                           "upper_half_good_share": 0.0}


def test_fits_without_a_score_are_left_out_of_that_ranks_figures_only():
    scores = [None, -4.0, None, -9.0, -12.0, float("nan")]
    figures = rank_quality(ERRORS, {"some": scores}, good_below_mm=8.0)
    assert figures["fits"] == 6 and figures["good_share"] == 0.5
    # 4, 9 and 12 mm are scored: the median score is -9, so 4 and 9 mm are the upper half, one of them good.
    assert figures["by_rank"]["some"] == {"scored": 3, "spearman": pytest.approx(1.0),
                                          "upper_half_good_share": 0.5}


def test_a_constant_score_has_no_correlation_and_too_few_fits_no_figures():
    flat = rank_quality(ERRORS, {"flat": [0.7] * 6}, good_below_mm=8.0)["by_rank"]["flat"]
    assert flat == {"scored": 6, "spearman": None, "upper_half_good_share": 0.5}  # the cut keeps them all
    few = rank_quality([3.0, 9.0], {"any": [1.0, 0.0]}, good_below_mm=8.0)
    assert few["by_rank"]["any"] == {"scored": 2, "spearman": None, "upper_half_good_share": None}
    assert rank_quality([], {"any": []}, good_below_mm=8.0)["good_share"] is None


def test_mismatched_scores_or_non_finite_errors_are_refused():
    with pytest.raises(ValueError, match="rank 'short': 2 scores for 3 fits"):
        rank_quality([1.0, 2.0, 3.0], {"short": [1.0, 2.0]}, good_below_mm=8.0)
    with pytest.raises(ValueError, match="finite millimetres"):
        rank_quality([1.0, float("inf")], {}, good_below_mm=8.0)
