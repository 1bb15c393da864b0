"""Verification policy of the paper ("Iterative Refinement"): the heuristic that accepts fits without a
human (D^h_i), and the selection of samples for manual verification (D^m_i).

Both are pure functions of plain values, so they are tested on hand-made cases; the database glue lives
in workers.tasks.records (heuristic on each new fit) and backend.services.review.review (queue building).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from backend.settings import Settings


@dataclass(frozen=True)
class HeuristicThresholds:
    """Paper defaults. Confidences in [0, 1]; IoU in [0, 1]; distances in metres."""

    min_mean_confidence: float = 0.8  # mean must be strictly above
    min_keypoint_confidence: float = 0.6  # each at least
    min_mean_iou: float = 0.7  # mean over views at least
    low_iou: float = 0.5  # a view below this counts as low
    max_low_iou_views: int = 2  # at most this many low views
    max_mean_distance_m: float = 0.005  # mean 3D keypoint distance at most
    max_keypoint_distance_m: float = 0.010  # every keypoint distance at most

    @classmethod
    def from_settings(cls, settings: Settings, prefix: str = "heuristic_") -> HeuristicThresholds:
        """The settings' thresholds: `prefix` "heuristic_" (MVNet's fits) or "detector_heuristic_" (detector fits)."""
        return cls(**{name: getattr(settings, prefix + name) for name in cls.__dataclass_fields__})


@dataclass(frozen=True)
class HeuristicResult:
    accepted: bool
    failed: tuple[str, ...]  # human-readable reasons, empty when accepted
    metrics: dict[str, float] = field(default_factory=dict)


def _clean(value: float) -> float:
    # Means of equal values carry float noise (21 x 0.8 averages to 0.8000000000000002); thresholds are
    # compared on values rounded far below any meaningful precision, so a boundary case is exact.
    return round(float(value), 12)


def heuristic_verdict(confidences: Sequence[float], view_ious: Iterable[float], predicted_m: Sequence[Sequence[float]],
                      fitted_m: Sequence[Sequence[float]], thresholds: HeuristicThresholds) -> HeuristicResult:
    """All three criteria of the paper.

    Args:
        confidences: (21,) MVNet keypoint confidences.
        view_ious: (C,) IoU between the predicted (HandSegNet) and the fitted model's mask, per view.
        predicted_m: (21, 3) MVNet keypoints, metres, world frame.
        fitted_m: (21, 3) keypoints of the fitted hand model, metres, world frame.
    """
    conf = np.asarray(confidences, dtype=np.float64)
    ious = np.asarray(list(view_ious), dtype=np.float64)
    pred = np.asarray(predicted_m, dtype=np.float64)
    fit = np.asarray(fitted_m, dtype=np.float64)
    if conf.ndim != 1 or conf.size == 0:
        raise ValueError(f"confidences must be (K,), got {conf.shape}")
    if pred.shape != fit.shape or pred.ndim != 2 or pred.shape[1] != 3 or pred.shape[0] != conf.size:
        raise ValueError(f"keypoints must both be ({conf.size}, 3), got {pred.shape} and {fit.shape}")
    if ious.size == 0:
        raise ValueError("at least one view IoU is needed")
    t = thresholds
    failed: list[str] = []
    mean_conf = _clean(conf.mean())
    if not mean_conf > t.min_mean_confidence:
        failed.append(f"mean confidence {mean_conf:.3f} is not above {t.min_mean_confidence}")
    if not (conf >= t.min_keypoint_confidence).all():
        failed.append(f"min keypoint confidence {conf.min():.3f} is below {t.min_keypoint_confidence}")
    mean_iou = _clean(ious.mean())
    low_views = int((ious < t.low_iou).sum())
    if not mean_iou >= t.min_mean_iou:
        failed.append(f"mean IoU {mean_iou:.3f} is below {t.min_mean_iou}")
    if low_views > t.max_low_iou_views:
        failed.append(f"{low_views} views have IoU below {t.low_iou} (at most {t.max_low_iou_views})")
    dist = np.linalg.norm(pred - fit, axis=1)
    mean_dist, max_dist = _clean(dist.mean()), _clean(dist.max())
    if not mean_dist <= t.max_mean_distance_m:
        failed.append(f"mean 3D distance {mean_dist * 1000:.2f} mm exceeds {t.max_mean_distance_m * 1000:g} mm")
    if not max_dist <= t.max_keypoint_distance_m:
        failed.append(f"max 3D distance {max_dist * 1000:.2f} mm exceeds {t.max_keypoint_distance_m * 1000:g} mm")
    metrics = {"mean_confidence": mean_conf, "min_confidence": float(conf.min()), "mean_iou": mean_iou,
               "low_iou_views": float(low_views), "mean_distance_m": mean_dist, "max_distance_m": max_dist}
    return HeuristicResult(accepted=not failed, failed=tuple(failed), metrics=metrics)


def detector_verdict(confidence: Sequence[float | None], view_ious: Iterable[float],
                     lifted_m: Sequence[Sequence[float | None]], fitted_m: Sequence[Sequence[float]],
                     thresholds: HeuristicThresholds) -> HeuristicResult:
    """The three criteria on a fit made from the pretrained detector (pre-annotation), the detector's lift in
    MVNet's role. A keypoint the detector did not lift (None / NaN: fewer than two views agreed) fails the fit.

    Args:
        confidence: (21,) the lifted keypoints' confidences in [0, 1] (workers.detector LiftedKeypoints).
        view_ious: (C,) IoU between the fitted model's mask and the view's chroma-key mask cut at the wrist.
        lifted_m: (21, 3) the detector's keypoints lifted over the views, metres, world frame.
        fitted_m: (21, 3) keypoints of the fitted hand model, metres, world frame.
    """
    conf = np.array(confidence, dtype=np.float64)  # None -> NaN
    lifted = np.array(lifted_m, dtype=np.float64)
    if lifted.ndim != 2 or lifted.shape[1] != 3 or conf.shape != (lifted.shape[0],):
        raise ValueError(f"lifted keypoints must be (K, 3) with (K,) confidences, got {lifted.shape}, {conf.shape}")
    missing = int((~np.isfinite(lifted).all(1) | ~np.isfinite(conf)).sum())
    if missing:
        return HeuristicResult(False, (f"{missing} keypoints not lifted by the detector (every one is needed)",),
                               {"keypoints_not_lifted": float(missing)})
    return heuristic_verdict(conf, view_ious, lifted, fitted_m, thresholds)


@dataclass(frozen=True)
class ReviewPolicy:
    """Manual-verification selection. `min_time_gap_s` between frames picked from one sequence;
    `min_pose_distance` is the Euclidean norm of the articulation parameters (the flat hand is 0).

    `capacity`: samples the reviewers can verify in a round (samples already in review count against it).
    None: the fixed policy (the percentile is a cut, the time gap a filter). A number: the queue is filled to
    it, the percentile and the time gap only ordering the candidates (`select_for_review`), unless
    `percentile_cut`: then the queue is filled from the percentile up only, the time gap still an order.
    `rank`: what the percentile and the order are over (`review_score`): "confidence", MVNet's mean confidence (the
    paper's), or "agreement", how close the fit came to the prediction it was fitted to."""

    min_confidence_percentile: float = 50.0
    min_time_gap_s: float = 1.0
    min_pose_distance: float = 0.5
    max_batch: int = 1000
    capacity: int | None = 1000
    percentile_cut: bool = True  # with a capacity: candidates under the percentile wait for the next round
    rank: str = "confidence"

    def __post_init__(self) -> None:
        if self.capacity is not None and self.capacity < 0:
            raise ValueError(f"capacity must be at least 0 samples (or None), not {self.capacity}")
        if self.rank not in REVIEW_RANKS:
            raise ValueError(f"rank must be one of {', '.join(REVIEW_RANKS)}, not {self.rank!r}")

    @classmethod
    def from_settings(cls, settings: Settings) -> ReviewPolicy:
        return cls(min_confidence_percentile=settings.review_min_confidence_percentile,
                   min_time_gap_s=settings.review_min_time_gap_s,
                   min_pose_distance=settings.review_min_pose_distance, max_batch=settings.review_max_batch,
                   capacity=settings.review_capacity_per_round or None,
                   percentile_cut=settings.review_percentile_cut, rank=settings.review_rank)


# What the review queue ranks fits from predictions by (ReviewPolicy.rank).
REVIEW_RANKS = ("confidence", "agreement")


def review_score(rank: str, confidence: float | None, heuristic: Mapping[str, Any] | None) -> float | None:
    """The score the review policy ranks a fitted sample by, higher first; None where there is none (fits from clicks:
    ranked after the scored ones).

    "confidence": MVNet's mean confidence (the paper's "sorted based on the confidence score of MVNet").
    "agreement": minus the mean 3D distance (mm) between the fit's keypoints and those it was fitted to (the
    heuristic's third criterion, `heuristic["mean_distance_m"]`; for a pre-annotation's fit, the detector's lift).
    Why: a network trained on a few dozen labels is not calibrated. On tuning seeds 57 (640 px) and 23 (320 px),
    round 1's fits from predictions that the heuristic did not accept, the mean confidence ranked their true
    vertex error at Spearman -0.27 and -0.06 (the most confident half held the cluttered sequences' worst fits), the
    fit's distance to its prediction at 0.85 and 0.87: a fit that strays from its keypoints is one the hand model and
    the masks would not follow (docs/evaluation.md, "The review queue")."""
    if rank == "confidence":
        return confidence
    if rank != "agreement":
        raise ValueError(f"rank must be one of {', '.join(REVIEW_RANKS)}, not {rank!r}")
    distance = (heuristic or {}).get("mean_distance_m")
    if not isinstance(distance, (int, float)) or isinstance(distance, bool) or not math.isfinite(distance):
        return None
    return -1000.0 * float(distance)


@dataclass(frozen=True)
class Candidate:
    sample_id: int
    sequence_id: int
    time_s: float
    score: float | None  # what the policy ranks by, higher first (review_score); None when the fit came from clicks
    pose_distance: float


def _scored(c: Candidate) -> bool:
    return c.score is not None and math.isfinite(c.score)


def _ranked(candidates: Sequence[Candidate], threshold: float) -> tuple[list[Candidate], list[Candidate]]:
    """(score from `threshold` up, the rest), each sorted by score, highest first; candidates without a score
    (fits from clicks, round 0) after the scored ones of the rest."""
    scored = [c for c in candidates if _scored(c)]

    def by_score(c: Candidate) -> tuple[float, int]:
        return -(c.score or 0.0), c.sample_id

    upper = sorted((c for c in scored if c.score >= threshold), key=by_score)
    lower = sorted((c for c in scored if c.score < threshold), key=by_score)
    unscored = sorted((c for c in candidates if not _scored(c)), key=lambda c: c.sample_id)
    return upper, lower + unscored


def select_for_review(candidates: Sequence[Candidate], policy: ReviewPolicy,
                      already_queued: Mapping[int, Sequence[float]] | None = None,
                      queued_scores: Sequence[float | None] = ()) -> list[int]:
    """Sample ids to put in front of reviewers, in the order picked.

    Candidates are the fitted samples the heuristic did not accept; flat hands (pose distance below the
    minimum) are never picked. `already_queued`: sequence id -> times (s) of its frames already in review;
    `queued_scores`: their scores (None where a fit has none).

    Fixed policy (`capacity` None, the paper's "Manual Verification"): those with a score (`review_score`: the
    paper's MVNet confidence, or the fit's agreement) are kept from the given percentile upwards (computed over
    these candidates) and sorted by score, highest first;
    candidates without one (fits from clicks, round 0) are all kept, after them. Frames are picked greedily,
    skipping any closer than `min_time_gap_s` to a frame already picked or queued in the same sequence; at most
    `max_batch`.

    Capacity policy: at most `capacity` minus the frames already queued (and `max_batch`); the percentile over
    the candidates and the frames already queued (a second build in a round does not lower it). Ranked as above but
    nothing is cut: first the candidates from the percentile up, spaced in time; then the rest, spaced in time
    against everything picked; then whatever is left, best first, however close in time. With `percentile_cut`
    only the candidates from the percentile up: spaced first, then however close in time. The spacing and the
    percentile spend the reviewers' capacity on the most confident, most varied frames first; they no longer
    leave capacity unused while fits wait.
    """
    scores = [c.score for c in candidates if _scored(c)]  # the percentile over all candidates, flat ones too
    if policy.capacity is not None:
        scores += [q for q in queued_scores if q is not None and math.isfinite(q)]
    threshold = float(np.percentile(scores, policy.min_confidence_percentile)) if scores else 0.0
    eligible = [c for c in candidates if c.pose_distance >= policy.min_pose_distance]
    upper, rest = _ranked(eligible, threshold)
    picked_times: dict[int, list[float]] = {k: list(v) for k, v in (already_queued or {}).items()}
    if policy.capacity is None:
        limit, passes = policy.max_batch, [(upper + [c for c in rest if c.score is None], True)]
    else:
        queued = sum(len(v) for v in picked_times.values())
        limit = max(0, min(policy.max_batch, policy.capacity - queued))
        passes = ([(upper, True), (upper, False)] if policy.percentile_cut
                  else [(upper, True), (rest, True), (upper + rest, False)])
    picked: list[int] = []
    taken: set[int] = set()
    for ranked, spaced in passes:
        for c in ranked:
            if len(picked) >= limit:
                return picked
            if c.sample_id in taken:
                continue
            times = picked_times.setdefault(c.sequence_id, [])
            if spaced and any(abs(c.time_s - t) < policy.min_time_gap_s for t in times):
                continue
            times.append(c.time_s)
            picked.append(c.sample_id)
            taken.add(c.sample_id)
    return picked
