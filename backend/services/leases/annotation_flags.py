"""No hand, skip and failed fits (models.flags): what an annotator says instead of clicking, kept out of the
fit and counted, and the rule that a sample someone passed on goes to someone else.

- "no hand" in a view comes with the submission (its clicks there must all be not annotated);
- "no hand" in the whole sample takes it out of the annotate queue as rejected (nothing to label, nothing to fit);
- "skip" gives it back to the queue for someone else;
- a fit that fails on a submission is recorded against its author, shown to them, and the sample goes to
  another annotator (the queue passes over it for them: backend.db.statements.passed_over).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import func, insert, select
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.capture import Sample
from backend.models.enums import FlagKind, LeaseKind, SampleState
from backend.models.fits import Fit
from backend.models.flags import AnnotationFlag
from backend.models.labels import Submission
from backend.services import audit
from backend.services.accounts.users import Actor
from backend.services.captures.state_machine import transition
from backend.services.leases import drafts, queues

_FLAGS = AnnotationFlag.__table__


@dataclass(frozen=True)
class SkipResult:
    sample_id: int
    kind: FlagKind
    state: SampleState


def pass_on(session: Session, user: Actor, sample_id: int, kind: FlagKind, reason: str,
            lease_token: str | None) -> SkipResult:
    """The leased sample skipped (back to the queue, for someone else) or marked "no hand" (out of the queue as
    rejected), with the reason; the lease and the annotate drafts go. Errors as the lease checks."""
    if kind not in (FlagKind.skip, FlagKind.no_hand):
        raise ValueError(f"kind {kind!r}: 'skip' or 'no_hand'")
    sample = queues.load_locked(session, sample_id)
    queues.check_lease(sample, user, LeaseKind.annotate, lease_token)
    session.add(AnnotationFlag(sample_id=sample_id, user_id=user.id, kind=kind.value, reason=reason))
    queues.clear(sample)
    drafts.delete_for_sample(session, sample_id, LeaseKind.annotate)
    if kind is FlagKind.no_hand:
        transition(session, sample, SampleState.rejected, user.id, reason=f"no hand: {reason}")
    audit.record(session, user.id, f"sample.{kind.value}", "sample", sample_id, reason=reason)
    return SkipResult(sample_id, kind, SampleState(sample.state))


def record_no_hand_views(session: Session, user_id: int, sample_id: int, submission_id: int,
                         view_ids: Iterable[int], now: datetime) -> None:
    """The views a submission said show no hand (its clicks there are all not annotated)."""
    rows = [{"sample_id": sample_id, "view_id": v, "user_id": user_id, "submission_id": submission_id,
             "kind": FlagKind.no_hand_view.value, "reason": "", "created_at": now} for v in view_ids]
    if rows:
        session.connection().execute(insert(_FLAGS), rows)


def record_fit_failure(session: Session, sample: Sample, error: str) -> None:
    """A failed fit against the newest submission of `sample` (its author is then passed over for it)."""
    newest = session.execute(select(Submission.id, Submission.user_id).where(Submission.sample_id == sample.id)
                             .order_by(Submission.id.desc()).limit(1)).first()
    session.add(AnnotationFlag(sample_id=sample.id, user_id=newest.user_id if newest else None,
                               submission_id=newest.id if newest else None, kind=FlagKind.fit_failed.value,
                               reason=error[:2000], created_at=utcnow()))


def fit_failures_of(session: Session, user: Actor, limit: int = 10) -> list[dict[str, Any]]:
    """The fits that failed on the caller's submissions, newest first."""
    f = _FLAGS.c
    rows = session.execute(select(f.sample_id, f.submission_id, f.reason, f.created_at)
                           .where(f.user_id == user.id, f.kind == FlagKind.fit_failed.value)
                           .order_by(f.id.desc()).limit(limit)).all()
    return [{"sample_id": r.sample_id, "submission_id": r.submission_id, "reason": r.reason, "at": r.created_at}
            for r in rows]


def last_fit_failure(session: Session, sample: Sample) -> dict[str, Any] | None:
    """Why the sample's newest fit failed, when it did (and no fit was made since): {reason, at} or None."""
    f = _FLAGS.c
    row = session.execute(select(f.reason, f.created_at).where(f.sample_id == sample.id,
                                                              f.kind == FlagKind.fit_failed.value)
                          .order_by(f.id.desc()).limit(1)).first()
    if row is None:
        return None
    if sample.current_fit_id is not None:
        fitted_at = session.execute(select(Fit.created_at).where(Fit.id == sample.current_fit_id)).scalar_one()
        if fitted_at >= row.created_at:
            return None
    return {"reason": row.reason, "at": row.created_at}


def counts(session: Session) -> dict[str, int]:
    """How many of each flag there are (no hand per view and per sample, skips, failed fits)."""
    found = dict(session.execute(select(_FLAGS.c.kind, func.count()).group_by(_FLAGS.c.kind)).all())
    # 'agreement' is the queue's bookkeeping (services.review.agreement), not something an annotator said
    return {kind.value: int(found.get(kind.value, 0)) for kind in FlagKind if kind is not FlagKind.agreement}
