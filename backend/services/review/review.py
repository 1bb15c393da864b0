"""Manual verification: building the reviewer queue by the paper's policy, and reviewer decisions."""

from __future__ import annotations

from typing import NamedTuple

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import Sample
from backend.models.enums import DecisionKind, LeaseKind, SampleState, Stream
from backend.models.fits import Fit
from backend.models.review import Decision
from backend.services import audit
from backend.services.accounts.users import Actor
from backend.services.captures.state_machine import transition
from backend.services.errors import ConflictError
from backend.services.leases import drafts, queues
from backend.services.review import label_audits
from backend.services.review.verification import Candidate, ReviewPolicy, review_score, select_for_review
from backend.services.rounds import rounds


def build_queue(session: Session, policy: ReviewPolicy, actor_id: int | None) -> list[int]:
    """Move the samples the policy picks from 'fitted' (not accepted by the heuristic) to 'in_review'; a fit a
    reviewer discarded is not offered again (its sample waits for the next round's fit)."""
    discarded = select(Decision.id).where(Decision.sample_id == Sample.id, Decision.fit_id == Sample.current_fit_id,
                                          Decision.decision == DecisionKind.discard)
    rows = session.execute(
        select(Sample).where(Sample.state == SampleState.fitted, Sample.current_fit_id.is_not(None),
                             ~discarded.exists())
        .with_for_update(skip_locked=True)
    ).scalars().all()
    heuristics = _fit_heuristics(session, [s.current_fit_id for s in rows], policy)
    candidates = [Candidate(s.id, s.sequence_id, s.time_s,
                            review_score(policy.rank, s.confidence, heuristics.get(s.current_fit_id)),
                            s.pose_distance or 0.0) for s in rows]
    queued: dict[int, list[float]] = {}
    in_review = session.execute(select(Sample.sequence_id, Sample.time_s, Sample.confidence, Sample.current_fit_id)
                                .where(Sample.state == SampleState.in_review)).all()
    heuristics.update(_fit_heuristics(session, [row[3] for row in in_review], policy))
    queued_scores: list[float | None] = []
    for sequence_id, time_s, confidence, fit_id in in_review:
        queued.setdefault(sequence_id, []).append(time_s)
        queued_scores.append(review_score(policy.rank, confidence, heuristics.get(fit_id)))
    picked = select_for_review(candidates, policy, queued, queued_scores)
    by_id = {s.id: s for s in rows}
    for sample_id in picked:
        transition(session, by_id[sample_id], SampleState.in_review, actor_id, reason="review policy")
    audit.record(session, actor_id, "review.build_queue", "round", rounds.open_round_id(session) or 0,
                 candidates=len(candidates), queued=len(picked))
    return picked


def _fit_heuristics(session: Session, fit_ids: list[int | None], policy: ReviewPolicy) -> dict[int, dict | None]:
    """fit id -> its heuristic record, where the policy ranks by one (ReviewPolicy.rank "agreement")."""
    wanted = [i for i in fit_ids if i is not None]
    if policy.rank == "confidence" or not wanted:
        return {}
    out: dict[int, dict | None] = {}
    for start in range(0, len(wanted), 500):  # bounded IN lists
        out.update(session.execute(select(Fit.id, Fit.heuristic).where(Fit.id.in_(wanted[start:start + 500]))).all())
    return out


class Decided(NamedTuple):
    """What a reviewer's decision did: the decision row, the sample after it, the stream the label joined (None when
    nothing joined), and whether the decision was an answer to a gold label (which moves nothing)."""

    decision: Decision
    sample: Sample
    stream: Stream | None
    gold_answer: bool = False


def decide(session: Session, user: Actor, sample_id: int, decision: DecisionKind, reason: str,
           lease_token: str | None) -> Decided:
    sample = queues.load_locked(session, sample_id)
    if sample.state == SampleState.accepted and not (sample.leased_by_id == user.id
                                                     and sample.lease_kind == LeaseKind.review):
        # An audit's lease that lapsed and went to another reviewer (or was decided): what to do, not the state
        # (which would tell the reviewer it was an accepted label).
        raise ConflictError(f"sample {sample_id} was decided or given to someone else while your review lease had "
                            "lapsed; ask for the next task")
    queues.check_lease(sample, user, LeaseKind.review, lease_token)
    if sample.current_fit_id is None:
        raise ConflictError(f"sample {sample_id} has no fit to verify")
    fit = session.get(Fit, sample.current_fit_id)
    stream: Stream | None = None
    round_ = rounds.open_round(session, user.id)
    if sample.state == SampleState.accepted:  # a blind audit of an accepted label (issue 40)
        row, sample, stream, gold = label_audits.decide(session, user, sample, decision, reason, round_)
        return Decided(row, sample, stream, gold)
    if decision is DecisionKind.accept:
        transition(session, sample, SampleState.accepted, user.id, reason=reason or "verified")
        # D^l: fits that used annotators' clicks; D^m: fits from predictions that a human verified.
        stream = Stream.annotated if fit is not None and fit.from_annotation else Stream.manual
        rounds.add_member(session, round_, sample_id, sample.current_fit_id, stream)
        label_audits.schedule(session, round_, sample_id, sample.current_fit_id, stream, user.id)
    elif decision is DecisionKind.reject:
        transition(session, sample, SampleState.rejected, user.id, reason=reason)
    elif decision is DecisionKind.discard:
        if fit is not None and fit.from_annotation:
            # Back in the pool, the next round would fit predictions over the annotators' clicks: their work lost.
            raise ConflictError(f"sample {sample_id}'s fit used annotators' clicks, so it cannot be discarded (the "
                                "next round would fit predictions instead): accept it, send it back for annotation, "
                                "or reject it")
        transition(session, sample, SampleState.fitted, user.id, reason=f"discarded: {reason or 'fit not good enough'}")
    else:
        transition(session, sample, SampleState.needs_annotation, user.id, reason=reason)
    queues.clear(sample)
    drafts.delete_for_sample(session, sample_id, LeaseKind.review)
    row = Decision(sample_id=sample_id, fit_id=sample.current_fit_id, round_id=round_.id, user_id=user.id,
                   decision=decision, reason=reason)
    session.add(row)
    session.flush()
    audit.record(session, user.id, "decision.create", "sample", sample_id, decision=decision.value,
                 reason=reason, stream=stream.value if stream else None)
    return Decided(row, sample, stream)
