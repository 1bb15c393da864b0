"""The review queue ranked by MVNet's confidence (the paper's) or by the fits' agreement with their predictions
(`review_rank`), through the admin's queue build on a real database."""

from __future__ import annotations

from sqlalchemy import text

from backend.services.review import review
from backend.services.review.verification import ReviewPolicy

# (MVNet's mean confidence, the fit's offset from the prediction in metres per axis): the two most confident fits
# strayed far from their predictions (34.6 and 52.0 mm), the two least confident stayed near (1.7 and 3.5 mm). Each
# fails the paper's heuristic (mean confidence under 0.8, or the distance over 5 mm), so all four wait for review.
FITS = ((0.75, 0.001), (0.70, 0.002), (0.95, 0.020), (0.90, 0.030))


def _fitted(env, h) -> list[int]:
    ids = h.seed(env, frames=len(FITS), cameras=2, state="fitting")
    for sample_id, (confidence, offset) in zip(ids, FITS, strict=True):
        h.record_fit(env, sample_id, prediction={"confidences": [confidence] * 21}, offset_m=offset)
    with env.session() as s:
        states = s.execute(text("SELECT DISTINCT state FROM samples")).scalars().all()
    assert states == ["fitted"], states
    return ids


def _queue(env, rank: str) -> list[int]:
    policy = ReviewPolicy(min_time_gap_s=0.0, capacity=None, rank=rank)  # the paper's fixed policy: the upper half
    with env.session() as session, session.begin():
        return review.build_queue(session, policy, None)


def test_the_paper_ranks_by_confidence_and_agreement_by_the_fits_distance_to_its_prediction(env, h):
    ids = _fitted(env, h)
    assert _queue(env, "confidence") == [ids[2], ids[3]]


def test_agreement_queues_the_fits_nearest_their_predictions(env, h):
    ids = _fitted(env, h)
    assert _queue(env, "agreement") == [ids[0], ids[1]]


def test_a_second_build_ranks_the_samples_already_in_review_by_the_same_score(env, h):
    ids = _fitted(env, h)
    assert _queue(env, "agreement") == [ids[0], ids[1]]
    # With a capacity the percentile is taken over the queued samples too: the two left are the worse half.
    policy = ReviewPolicy(min_time_gap_s=0.0, capacity=3, rank="agreement")
    with env.session() as session, session.begin():
        assert review.build_queue(session, policy, None) == []
