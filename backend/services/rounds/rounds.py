"""Bootstrap rounds: D_{i+1} = D_i + D^h_i + D^m_i + D^l_i.

One round is open ('running') at a time; accepted samples join it by stream. Launching round i+1
completes round i and queues the round job (train MVNet and HandSegNet on D_{i+1}, predict the rest, fit,
heuristic, build the review queue) for the workers; if that job fails, round i is open again as it was
(services.jobs.round_failure). A decision with no round open opens round 0 (the initial, manually annotated D_0).
"""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.capture import Sample
from backend.models.enums import JobKind, JobState, RoundState, Stream
from backend.models.jobs import Job
from backend.models.labels import Click, Submission
from backend.models.review import Decision, Round, RoundMember
from backend.schemas.admin import DecisionCounts, RoundStats, Statistics, StreamCounts
from backend.services import audit
from backend.services.errors import ConflictError, NotFoundError
from backend.services.jobs import jobs, round_failure


def open_round_id(session: Session) -> int | None:
    return session.execute(select(Round.id).where(Round.state == RoundState.running)
                           .order_by(Round.index.desc()).limit(1)).scalar_one_or_none()


def open_round(session: Session, actor_id: int | None) -> Round:
    """The running round, or a new one after the last."""
    round_ = session.execute(select(Round).where(Round.state == RoundState.running)
                             .order_by(Round.index.desc()).limit(1).with_for_update()).scalar_one_or_none()
    if round_ is not None:
        return round_
    last = session.execute(select(func.max(Round.index))).scalar_one()
    round_ = Round(index=0 if last is None else last + 1, state=RoundState.running, counts={},
                   created_by_id=actor_id)
    session.add(round_)
    session.flush()
    audit.record(session, actor_id, "round.open", "round", round_.id, index=round_.index)
    return round_


def add_member(session: Session, round_: Round, sample_id: int, fit_id: int | None, stream: Stream) -> None:
    session.add(RoundMember(round_id=round_.id, sample_id=sample_id, fit_id=fit_id, stream=stream))
    audit.record(session, None, "round.member", "round", round_.id, sample_id=sample_id, stream=stream.value)


def list_rounds(session: Session) -> list[Round]:
    return list(session.execute(select(Round).order_by(Round.index)).scalars())


def get_round(session: Session, round_id: int) -> Round:
    round_ = session.get(Round, round_id)
    if round_ is None:
        raise NotFoundError(f"round {round_id} not found")
    return round_


def _counts(session: Session, round_id: int) -> dict[str, int]:
    rows = session.execute(select(RoundMember.stream, func.count()).where(RoundMember.round_id == round_id)
                           .group_by(RoundMember.stream)).all()
    return {stream: int(n) for stream, n in rows}


def accepted_labels(session: Session) -> int:
    """Accepted samples with a fit in any round: what the next round's networks train on (D_{i+1})."""
    return session.execute(select(func.count()).select_from(RoundMember)
                           .where(RoundMember.fit_id.is_not(None))).scalar_one()


ROUND_WORK = (JobKind.round, JobKind.preannotate)  # what a round (round 0: the detector's) runs


def launch_refusal(session: Session, min_training_samples: int) -> str | None:
    """Why a round cannot be launched now, in plain words; None when it can. One round at a time: while a round's
    job (or round 0's pre-annotation) is queued or running, launching would complete the open round before its
    models exist and train the next on labels still being made."""
    busy = session.execute(select(Job.id, Job.kind, Job.state, Job.round_id).where(
        Job.kind.in_(ROUND_WORK), Job.state.in_([JobState.queued, JobState.running]))
        .order_by(Job.id).limit(1)).first()
    if busy is not None:
        job_id, kind, state, round_id = busy
        kind, state = getattr(kind, "value", kind), getattr(state, "value", state)
        index = session.execute(select(Round.index).where(Round.id == round_id)).scalar_one_or_none() \
            if round_id is not None else None
        what = f"round {index}'s job {job_id}" if index is not None else f"{kind} job {job_id}"
        return (f"one round at a time: {what} is {state} still. Wait until it is done (its progress is shown "
                "here), or cancel it.")
    n = accepted_labels(session)
    if n >= min_training_samples:
        return None
    return (f"a round trains its networks on the accepted labels: {n} accepted so far, at least "
            f"{min_training_samples} needed. Accept {min_training_samples - n} more in review first.")


def launch(session: Session, queue: jobs.JobQueue, actor_id: int, mvnet_version: str | None,
           handsegnet_version: str | None, note: str, min_training_samples: int = 1) -> tuple[Round, Job]:
    """Complete the open round and launch the next; ConflictError (nothing written) while a round's job is still
    queued or running, or fewer than `min_training_samples` labels are accepted (its training would fail)."""
    queue.ensure_available()  # an outage first (503): it is no reason to go and accept more labels
    current = open_round(session, actor_id)  # locked first: a second launch at once waits, then is refused
    refusal = launch_refusal(session, min_training_samples)
    if refusal is not None:
        raise ConflictError(f"cannot launch a round yet: {refusal}")
    before = round_failure.snapshot(current)  # restored if the round's job fails (services.jobs.round_failure)
    current.state = RoundState.completed
    current.finished_at = utcnow()
    current.counts = _counts(session, current.id)
    audit.record(session, actor_id, "round.complete", "round", current.id, counts=current.counts)
    session.flush()
    last = session.execute(select(func.max(Round.index))).scalar_one()  # a failed round keeps its index
    round_ = Round(index=max(current.index, last) + 1, state=RoundState.running, mvnet_version=mvnet_version,
                   handsegnet_version=handsegnet_version, note=note, counts={}, created_by_id=actor_id)
    session.add(round_)
    session.flush()
    audit.record(session, actor_id, "round.launch", "round", round_.id, index=round_.index)
    job = jobs.create(session, queue, JobKind.round, actor_id=actor_id, round_id=round_.id,
                      payload={"train_on_rounds_up_to": current.index, "reopen_on_failure": before})
    return round_, job


def cancel(session: Session, queue: jobs.JobQueue, round_id: int, actor_id: int) -> Round:
    round_ = get_round(session, round_id)
    if round_.state != RoundState.running:
        raise ConflictError(f"round {round_.index} is '{round_.state}'; only a running round can be cancelled")
    # The round job's row first, then its children (the workers' progress writers lock in the same order).
    round_job = session.execute(select(Job).where(Job.round_id == round_id, Job.kind == JobKind.round)
                                .limit(1).with_for_update()).scalar_one_or_none()
    # As a failed round: the round its launch completed is open again, as it was (services.jobs.round_failure).
    reopened = round_failure.reopen_previous(session, round_job, None, outcome=RoundState.cancelled) \
        if round_job is not None else None
    if reopened is None and round_.state == RoundState.running:
        round_.state = RoundState.cancelled
        round_.finished_at = utcnow()
        round_.counts = _counts(session, round_.id)
    for job in session.execute(select(Job).where(Job.round_id == round_id,
                                                 Job.state.in_([JobState.queued, JobState.running]))
                               .order_by(Job.id)).scalars():
        jobs.cancel(session, queue, job.id, actor_id)
    audit.record(session, actor_id, "round.cancel", "round", round_.id)
    return round_


def statistics(session: Session) -> Statistics:
    by_state = dict(session.execute(select(Sample.state, func.count()).group_by(Sample.state)).all())
    members = session.execute(select(RoundMember.round_id, RoundMember.stream, func.count())
                              .group_by(RoundMember.round_id, RoundMember.stream)).all()
    per_round: dict[int, dict[str, int]] = {}
    for round_id, stream, n in members:
        per_round.setdefault(round_id, {})[stream] = int(n)
    decided: dict[int, dict[str, int]] = {}
    for round_id, kind, n in session.execute(select(Decision.round_id, Decision.decision, func.count())
                                             .where(Decision.by_heuristic.is_(False), Decision.round_id.is_not(None))
                                             .group_by(Decision.round_id, Decision.decision)):
        decided.setdefault(round_id, {})[kind] = int(n)
    stats, size = [], 0
    for round_ in list_rounds(session):
        if round_.state == RoundState.cancelled:  # undone by its admin: its samples went back to the round before
            continue
        counts = StreamCounts(**per_round.get(round_.id, {}))
        added = counts.heuristic + counts.manual + counts.annotated
        size += added
        stats.append(RoundStats(round_id=round_.id, index=round_.index, state=round_.state, added=counts,
                                added_total=added, dataset_size_after=size,
                                decisions=DecisionCounts(**decided.get(round_.id, {}))))
    return Statistics(
        samples_by_state={k: int(v) for k, v in by_state.items()},
        rounds=stats,
        submissions=session.execute(select(func.count()).select_from(Submission)).scalar_one(),
        # Points placed by hand: not the not-annotated rows every submission has (48 a sample), nor accepted
        # proposals (issue 38: '336 clicks' was submissions x 48).
        clicks=session.execute(select(func.count()).select_from(Click).where(
            Click.x_px.is_not(None), Click.from_proposal.is_(False))).scalar_one(),
    )
