"""A failed or cancelled round leaves the round table as it was before its launch.

Launching round i+1 completes round i (services.rounds.rounds.launch) before any training has run. When the round's
job then fails (too few labels for the networks, a training error, a worker that gave up), round i+1 is marked
'failed' and round i is open again, with the state and counts it had at the launch (kept in the round job's
payload as `reopen_on_failure`). Samples accepted while round i+1 was open (reviewers' decisions, the
heuristic) move to round i: they joined the open round, and a later launch trains on them. The failed round
keeps its index (its jobs and checkpoints name it); the next launch takes the index after it.

Called by services.jobs.jobs.finish for every round job that fails, and by services.rounds.rounds.cancel when an admin
cancels a running round (marked 'cancelled' instead, no failure text), in the same transaction.
"""

from __future__ import annotations

import logging
from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.enums import JobKind, JobState, RoundState
from backend.models.jobs import Job
from backend.models.review import Decision, Round, RoundMember
from backend.services import audit

logger = logging.getLogger(__name__)


def snapshot(round_: Round) -> dict[str, Any]:
    """What `reopen_previous` restores of the round completed by a launch: its state and counts before it."""
    return {"round_id": round_.id, "state": str(round_.state), "counts": dict(round_.counts or {})}


def reopen_previous(session: Session, round_job: Job, error: str | None, *,
                    outcome: RoundState = RoundState.failed) -> Round | None:
    """Mark the round job's round `outcome` ('failed' or 'cancelled') and reopen the round its launch
    completed; that round, or None when there was nothing to undo (the round is not running: cancelled,
    already failed; or a later round exists, which the reopening would contradict). On a failure the round's
    other training job is stopped here; a cancel stops its jobs itself (services.rounds.rounds.cancel)."""
    round_ = session.get(Round, round_job.round_id) if round_job.round_id is not None else None
    if round_ is None or round_.state != RoundState.running:
        return None
    now = utcnow()
    failed = outcome == RoundState.failed
    action = "round.fail" if failed else "round.reopen"
    round_.state = outcome
    round_.finished_at = now
    round_.failure = (error or "its job failed")[:2000] if failed else None
    if failed:  # the other network may still be training for this round: stopped (its progress reporter sees it)
        for job in session.execute(select(Job).where(Job.round_id == round_.id, Job.kind == JobKind.train,
                                                     Job.state.in_([JobState.queued, JobState.running]))).scalars():
            job.state, job.finished_at, job.message = JobState.cancelled, now, ""
            job.error = f"round {round_.index} failed: {error or 'its job failed'}"[:2000]
    later = session.execute(select(Round.id).where(Round.index > round_.index).limit(1)).scalar_one_or_none()
    before = dict((round_job.payload or {}).get("reopen_on_failure") or {})
    previous = session.get(Round, before["round_id"]) if before.get("round_id") is not None else \
        session.execute(select(Round).where(Round.index < round_.index).order_by(Round.index.desc())
                        .limit(1)).scalar_one_or_none()
    if later is not None or previous is None or previous.state != RoundState.completed:
        audit.record(session, None, action, "round", round_.id, error=error, reopened=None)
        logger.warning("round %s %s (%s); no earlier round reopened", round_.index, outcome, error)
        round_.counts = _member_counts(session, round_.id)
        return None
    moved = session.execute(update(RoundMember).where(RoundMember.round_id == round_.id)
                            .values(round_id=previous.id)).rowcount
    session.execute(update(Decision).where(Decision.round_id == round_.id).values(round_id=previous.id))
    round_.counts = {}
    previous.state = before.get("state") or RoundState.running
    previous.finished_at = None
    previous.counts = dict(before.get("counts") or {})
    audit.record(session, None, action, "round", round_.id, error=error, reopened=previous.id,
                 members_moved=moved)
    logger.warning("round %s %s (%s); round %s is open again (%d accepted samples moved to it)", round_.index,
                   outcome, error, previous.index, moved)
    return previous


def _member_counts(session: Session, round_id: int) -> dict[str, int]:
    rows = session.execute(select(RoundMember.stream, func.count()).where(RoundMember.round_id == round_id)
                           .group_by(RoundMember.stream)).all()
    return {str(stream): int(n) for stream, n in rows}
