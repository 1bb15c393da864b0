"""The paper's heuristic at each threshold, and the reviewer-queue policy, on hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

from backend.services.review.verification import (
    Candidate,
    HeuristicThresholds,
    ReviewPolicy,
    heuristic_verdict,
    review_score,
    select_for_review,
)
from backend.settings import Settings

T = HeuristicThresholds()
EPS = 1e-4
KP = np.zeros((21, 3))


def verdict(conf=None, ious=None, offsets_m=None):
    conf = [0.9] * 21 if conf is None else conf
    ious = [0.9] * 8 if ious is None else ious
    fitted = KP.copy()
    if offsets_m is not None:
        fitted[:, 0] += offsets_m
    return heuristic_verdict(conf, ious, KP, fitted, T)


def test_all_good_is_accepted():
    result = verdict()
    assert result.accepted and result.failed == ()


@pytest.mark.parametrize(("mean", "accepted"), [(0.8 + EPS, True), (0.8, False), (0.8 - EPS, False)])
def test_mean_confidence_must_be_above_0_8(mean, accepted):
    assert verdict(conf=[mean] * 21).accepted is accepted


@pytest.mark.parametrize(("low", "accepted"), [(0.6, True), (0.6 - EPS, False)])
def test_every_keypoint_confidence_at_least_0_6(low, accepted):
    conf = [0.95] * 20 + [low]  # mean stays above 0.8
    result = verdict(conf=conf)
    assert result.accepted is accepted
    if not accepted:
        assert "min keypoint confidence" in result.failed[0]


@pytest.mark.parametrize(("mean_iou", "accepted"), [(0.7, True), (0.7 - EPS, False)])
def test_mean_iou_at_least_0_7(mean_iou, accepted):
    assert verdict(ious=[mean_iou] * 8).accepted is accepted


@pytest.mark.parametrize(("n_low", "accepted"), [(2, True), (3, False)])
def test_at_most_two_views_below_0_5(n_low, accepted):
    ious = [0.5 - EPS] * n_low + [1.0] * (8 - n_low)  # mean stays >= 0.7
    assert np.mean(ious) >= 0.7
    assert verdict(ious=ious).accepted is accepted


def test_iou_exactly_0_5_is_not_low():
    ious = [0.5] * 3 + [1.0] * 5
    assert verdict(ious=ious).accepted


@pytest.mark.parametrize(("mean_mm", "accepted"), [(5.0 - 1e-3, True), (5.0 + 1e-3, False)])
def test_mean_distance_at_most_5_mm(mean_mm, accepted):
    assert verdict(offsets_m=np.full(21, mean_mm / 1000)).accepted is accepted


@pytest.mark.parametrize(("max_mm", "accepted"), [(10.0 - 1e-3, True), (10.0 + 1e-3, False)])
def test_no_keypoint_farther_than_10_mm(max_mm, accepted):
    offsets = np.zeros(21)
    offsets[3] = max_mm / 1000  # mean stays < 5 mm
    result = verdict(offsets_m=offsets)
    assert result.accepted is accepted
    assert result.metrics["max_distance_m"] == pytest.approx(max_mm / 1000)


def test_thresholds_are_configurable():
    loose = HeuristicThresholds(min_mean_confidence=0.5)
    assert heuristic_verdict([0.7] * 21, [0.9], KP, KP, loose).accepted


def test_shape_errors():
    with pytest.raises(ValueError, match="keypoints"):
        heuristic_verdict([0.9] * 21, [0.9], KP[:20], KP, T)


def _c(i, t, conf, pose=1.0, seq=1):
    return Candidate(sample_id=i, sequence_id=seq, time_s=t, score=conf, pose_distance=pose)


FIXED = {"capacity": None}  # the fixed policy: the percentile a cut, the time gap a filter
FILL = {"percentile_cut": False}  # with a capacity, the percentile only orders


def test_policy_keeps_the_upper_half_sorted_by_confidence():
    cands = [_c(i, 10.0 * i, conf) for i, conf in enumerate([0.1, 0.2, 0.3, 0.4, 0.5, 0.6], start=1)]
    assert select_for_review(cands, ReviewPolicy(**FIXED)) == [6, 5, 4]


def test_policy_temporal_gap_within_a_sequence_only():
    cands = [_c(1, 0.0, 0.9), _c(2, 0.5, 0.8), _c(3, 1.0, 0.7), _c(4, 0.5, 0.85, seq=2)]
    policy = ReviewPolicy(min_confidence_percentile=0, min_time_gap_s=1.0, **FIXED)
    assert select_for_review(cands, policy) == [1, 4, 3]


def test_policy_drops_flat_hands_and_respects_queued_frames():
    cands = [_c(1, 0.0, 0.9, pose=0.1), _c(2, 5.0, 0.8), _c(3, 9.0, 0.7)]
    policy = ReviewPolicy(min_confidence_percentile=0, min_time_gap_s=2.0, min_pose_distance=0.5, **FIXED)
    assert select_for_review(cands, policy, already_queued={1: [8.5]}) == [2]


def test_policy_keeps_unscored_candidates_after_scored_and_caps_batch():
    cands = [_c(1, 0.0, None), _c(2, 10.0, 0.9), _c(3, 20.0, None)]
    assert select_for_review(cands, ReviewPolicy(**FIXED)) == [2, 1, 3]
    assert select_for_review(cands, ReviewPolicy(max_batch=2, **FIXED)) == [2, 1]


# --- the capacity policy: the queue filled to the reviewers' capacity ------------------------------------------


def test_capacity_fills_past_the_median_and_the_time_gap():
    # Six frames close in time in one sequence: the fixed policy keeps the upper half 1 s apart (one frame); with
    # capacity for all, every frame is offered: the spaced upper half (1), the spaced rest (6), then the rest.
    times, confs = [0.0, 0.2, 0.4, 0.6, 0.8, 1.5], [0.6, 0.5, 0.4, 0.3, 0.2, 0.1]
    cands = [_c(i, t, conf) for i, (t, conf) in enumerate(zip(times, confs, strict=True), start=1)]
    assert select_for_review(cands, ReviewPolicy(**FIXED)) == [1]
    assert select_for_review(cands, ReviewPolicy(capacity=10, **FILL)) == [1, 6, 2, 3, 4, 5]


def test_capacity_spends_itself_on_the_most_confident_spread_frames():
    # Capacity 3 of 4: the upper half spaced (1; 2 is 0.5 s from it), then the rest spaced (3, 4): 2, more
    # confident than 3 and 4 but 0.5 s from 1, is left for the next round.
    cands = [_c(1, 0.0, 0.9), _c(2, 0.5, 0.8), _c(3, 5.0, 0.7), _c(4, 7.0, 0.1)]
    assert select_for_review(cands, ReviewPolicy(capacity=3, **FILL)) == [1, 3, 4]
    assert select_for_review(cands, ReviewPolicy(capacity=2, **FILL)) == [1, 3]


def test_capacity_spreads_over_sequences_before_filling_one():
    # Two sequences; the most confident four frames are all in sequence 1, 0.1 s apart.
    cands = [_c(i, 0.1 * i, 0.9 - 0.01 * i) for i in range(1, 5)] + [_c(10, 0.0, 0.5, seq=2)]
    picked = select_for_review(cands, ReviewPolicy(min_confidence_percentile=0, capacity=2, **FILL))
    assert picked == [1, 10]


def test_capacity_counts_frames_already_in_review_and_never_picks_flat_hands():
    cands = [_c(1, 0.0, 0.9, pose=0.1), _c(2, 5.0, 0.8), _c(3, 9.0, 0.7), _c(4, 20.0, 0.6)]
    policy = ReviewPolicy(min_confidence_percentile=0, min_time_gap_s=2.0, capacity=3, **FILL)
    # One frame already queued (sequence 1 at 8.5 s): two more fit; 3 is 0.5 s from it, so 4 comes first.
    assert select_for_review(cands, policy, already_queued={1: [8.5]}) == [2, 4]
    assert select_for_review(cands, policy, already_queued={1: [8.5, 30.0, 40.0]}) == []
    assert 1 not in select_for_review(cands, ReviewPolicy(capacity=100, **FILL))


def test_capacity_is_bounded_by_max_batch_and_ranks_unscored_last():
    cands = [_c(1, 0.0, None), _c(2, 10.0, 0.9), _c(3, 20.0, 0.2), _c(4, 30.0, None)]
    assert select_for_review(cands, ReviewPolicy(capacity=10, **FILL)) == [2, 3, 1, 4]
    assert select_for_review(cands, ReviewPolicy(capacity=10, max_batch=2, **FILL)) == [2, 3]


def test_capacity_with_the_percentile_as_a_cut_fills_from_the_upper_half_only():
    times, confs = [0.0, 0.2, 0.4, 0.6, 0.8, 1.5], [0.6, 0.5, 0.4, 0.3, 0.2, 0.1]
    cands = [_c(i, t, conf) for i, (t, conf) in enumerate(zip(times, confs, strict=True), start=1)]
    # The upper half (1, 2, 3): 1 spaced first, then 2 and 3 though close in time; 4-6 wait for the next round.
    assert select_for_review(cands, ReviewPolicy(capacity=10, percentile_cut=True)) == [1, 2, 3]
    assert select_for_review(cands, ReviewPolicy(capacity=2, percentile_cut=True)) == [1, 2]


def test_a_second_build_in_a_round_keeps_the_percentile_of_the_first():
    # The first build queued the upper half of eight (0.9-0.6); building again over the four left must not take the
    # upper half of those: the percentile is over the queued frames too.
    left = [_c(i, 10.0 * i, conf) for i, conf in enumerate([0.5, 0.4, 0.3, 0.2], start=5)]
    queued = {1: [0.0, 10.0, 20.0, 30.0]}
    policy = ReviewPolicy(capacity=100)
    assert select_for_review(left, policy, queued) == [5, 6]  # without their confidences: the floor drops
    assert select_for_review(left, policy, queued, queued_scores=[0.9, 0.8, 0.7, 0.6]) == []
    assert select_for_review(left, ReviewPolicy(capacity=100, **FILL), queued, [0.9, 0.8, 0.7, 0.6]) == [5, 6, 7, 8]


def test_capacity_comes_from_settings_and_zero_means_the_fixed_policy():
    assert ReviewPolicy.from_settings(Settings(review_capacity_per_round=0)).capacity is None
    assert ReviewPolicy.from_settings(Settings(review_capacity_per_round=40)).capacity == 40
    assert ReviewPolicy.from_settings(Settings()).percentile_cut is True
    assert ReviewPolicy.from_settings(Settings(review_percentile_cut=False)).percentile_cut is False
    with pytest.raises(ValueError, match="capacity"):
        ReviewPolicy(capacity=-1)


def test_the_detectors_heuristic_needs_every_keypoint_lifted_then_applies_the_three_criteria():
    from backend.services.review.verification import detector_verdict

    t = HeuristicThresholds.from_settings(Settings(), "detector_heuristic_")
    assert (t.min_mean_confidence, t.max_mean_distance_m, t.max_keypoint_distance_m) == (0.5, 0.010, 0.025)
    lifted = [[0.0, 0.0, 0.0]] * 21
    fitted = np.zeros((21, 3))
    fitted[:, 0] += 0.008  # 8 mm off everywhere: within the detector's 10 mm, beyond MVNet's 5 mm
    assert detector_verdict([0.6] * 21, [0.8] * 8, lifted, fitted, t).accepted
    assert not heuristic_verdict([0.6] * 21, [0.8] * 8, lifted, fitted, T).accepted
    one_missing = [*lifted[:20], [None, None, None]]
    result = detector_verdict([0.6] * 20 + [None], [0.8] * 8, one_missing, fitted, t)
    assert not result.accepted and result.failed == ("1 keypoints not lifted by the detector (every one is needed)",)
    low = detector_verdict([0.45] * 21, [0.8] * 8, lifted, fitted, t)
    assert not low.accepted and low.failed[0].startswith("mean confidence 0.450")
    with pytest.raises(ValueError, match="lifted keypoints"):
        detector_verdict([0.6] * 21, [0.8] * 8, [[0.0, 0.0]] * 21, fitted, t)


def test_records_names_the_detector_source_as_the_pre_annotation_does():
    from workers.tasks.detection_inputs import SOURCE
    from workers.tasks.records import DETECTOR_SOURCE

    assert DETECTOR_SOURCE == SOURCE


def test_review_score_by_confidence_or_by_the_fits_agreement_with_its_prediction():
    heuristic = {"mean_distance_m": 0.0042, "mean_confidence": 0.5}
    assert review_score("confidence", 0.7, heuristic) == 0.7
    assert review_score("agreement", 0.7, heuristic) == pytest.approx(-4.2)  # minus millimetres: nearer is higher
    assert review_score("agreement", 0.7, None) is None  # a fit from clicks has no prediction to agree with
    assert review_score("agreement", 0.7, {"mean_distance_m": float("nan")}) is None
    assert review_score("agreement", 0.7, {"mean_distance_m": True}) is None
    with pytest.raises(ValueError, match="rank must be one of confidence, agreement"):
        review_score("loss", 0.7, heuristic)
    with pytest.raises(ValueError, match="rank must be one of"):
        ReviewPolicy(rank="loss")


def test_agreement_puts_an_unscored_fit_after_the_scored_ones_as_confidence_does():
    cands = [_c(1, 0.0, None), _c(2, 10.0, -30.0), _c(3, 20.0, -2.0), _c(4, 30.0, -8.0)]
    assert select_for_review(cands, ReviewPolicy(min_confidence_percentile=0, **FIXED)) == [3, 4, 2, 1]
