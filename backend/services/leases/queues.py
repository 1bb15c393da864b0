"""Work queues with leases: an expiring lock held in the sample's row.

Taking a lease is one atomic statement, `UPDATE samples SET lease... WHERE id = (SELECT id ... LIMIT 1
FOR UPDATE SKIP LOCKED) RETURNING id`: on PostgreSQL concurrent callers skip each other's rows; on SQLite
every transaction begins IMMEDIATE (backend.db.session), so writers are serialised. An expired lease is
simply a free row again: no sweeper is needed for the sample to return to the queue.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Protocol

from sqlalchemy import and_, exists, func, or_, select, update
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.db.statements.lease_statement import QUEUE_STATE, acquire_statement, free_pick
from backend.db.statements.passed_over import passed_over
from backend.models.capture import Sample
from backend.models.drafts import Draft
from backend.models.enums import LeaseKind
from backend.services import audit
from backend.services.accounts.users import Actor
from backend.services.captures.samples import ViewInfo
from backend.services.errors import ConflictError, LeaseExpiredError, NotFoundError, PermissionDeniedError


@dataclass(frozen=True, slots=True)
class SampleHead:
    """The sample columns a task shows, returned by the statement that took or renewed the lease."""

    id: int
    sequence_id: int
    frame_index: int
    time_s: float
    state: str
    current_fit_id: int | None


@dataclass(frozen=True)
class Lease:
    sample_id: int
    token: str
    expires_at: datetime
    kind: LeaseKind
    head: SampleHead | None = None
    # Returned with the lease by PostgreSQL's one-statement acquire (lease_statement): what a task shows.
    views: tuple[ViewInfo, ...] | None = None
    sequence: str | None = None
    side: str | None = None  # the sequence's hand, with `sequence`


def _lease_of(sample: Sample) -> Lease:
    assert sample.lease_token is not None and sample.lease_expires_at is not None
    return Lease(sample.id, sample.lease_token, sample.lease_expires_at, LeaseKind(sample.lease_kind))


_SAMPLES = Sample.__table__  # Core columns: the hot path skips the ORM's statement machinery
_DRAFTS = Draft.__table__


HEAD_COLUMNS = (_SAMPLES.c.id, _SAMPLES.c.sequence_id, _SAMPLES.c.frame_index, _SAMPLES.c.time_s,
                _SAMPLES.c.state, _SAMPLES.c.current_fit_id)  # SampleHead's fields, in order


def acquire(session: Session, user: Actor, kind: LeaseKind, lease_seconds: int,
            now: datetime | None = None, *, sole_statement: bool = False) -> Lease | None:
    """The caller's live lease of this kind if it has one (renewed), else a new one; None if the queue is
    empty. Never hands a sample held by someone else.

    PostgreSQL: one statement (lease_statement). `sole_statement`: the caller's request runs nothing else
    in its transaction, so when the session has not begun one yet the statement runs in autocommit mode
    (atomic on its own), sparing the BEGIN and COMMIT round trips.

    Core statements on the session's connection (no ORM objects): renewing the own lease is one
    UPDATE ... RETURNING (usually matching nothing), taking a free sample another; the audit row a third."""
    now = now or utcnow()
    expires = now + timedelta(seconds=lease_seconds)
    state = QUEUE_STATE[kind]
    if session.get_bind().dialect.name == "postgresql":
        if sole_statement and not session.in_transaction():
            session.connection(execution_options={"isolation_level": "AUTOCOMMIT"})
        return _acquire_in_one_statement(session, user, kind, expires, now)
    conn = session.connection()
    c = _SAMPLES.c
    mine = (c.leased_by_id == user.id, c.lease_kind == kind.value, c.state == state.value, c.lease_expires_at > now)
    # The conditions again outside the subquery: on PostgreSQL they are re-checked on the newest row
    # version if a concurrent transaction (the same user's submit) changed it meanwhile.
    # Of two held (the one on screen and the prefetched), the one with a draft: a reload shows the work.
    drafted = exists().where(_DRAFTS.c.sample_id == c.id, _DRAFTS.c.kind == kind.value,
                             _DRAFTS.c.user_id == user.id)
    own = conn.execute(
        update(_SAMPLES)
        .where(c.id == select(c.id).where(*mine).order_by(drafted.desc(), c.id).limit(1).scalar_subquery(), *mine)
        .values(lease_expires_at=expires)
        .returning(*HEAD_COLUMNS, c.lease_token)
    ).first()
    if own is not None:
        return Lease(own.id, own.lease_token, expires, kind, SampleHead(*own[:6]))
    # A free sample the caller left work on (its lease lapsed, or they signed out) before any other.
    return (take_free(session, user, kind, expires, now, drafted_by=user.id)
            or take_free(session, user, kind, expires, now))


def _acquire_in_one_statement(session: Session, user: Actor, kind: LeaseKind, expires: datetime,
                              now: datetime) -> Lease | None:
    """PostgreSQL: `acquire` (lease, audit row, views, sequence name) in one round trip (lease_statement)."""
    rows = session.connection().execute(acquire_statement(kind), {
        "user_id": user.id, "now": now, "expires": expires, "token": secrets.token_urlsafe(16)}).all()
    if not rows:
        return None
    first = rows[0]
    views = tuple(ViewInfo(r.view_id, r.camera, r.width, r.height, r.mask_id) for r in rows if r.view_id is not None)
    return Lease(first.id, first.lease_token, expires, kind, SampleHead(*first[:6]), views, first.sequence,
                 first.side)


def take_free(session: Session, user: Actor, kind: LeaseKind, expires: datetime, now: datetime, *,
              action: str = "lease.acquire", exclude_sample_id: int | None = None,
              drafted_by: int | None = None) -> Lease | None:
    """Lease the first free sample of the queue (in the queue's order, skipping rows other transactions
    hold) until `expires`, with its audit row; None when no sample is free. With `drafted_by`, only
    samples that user has a draft of in this queue (found through the drafts' user index)."""
    c = _SAMPLES.c
    conditions = []
    if exclude_sample_id is not None:
        conditions.append(c.id != exclude_sample_id)
    if kind is LeaseKind.annotate:  # not a sample this person skipped or whose fit failed on their work
        conditions.append(passed_over(c.id, user.id))
    if drafted_by is not None:
        conditions.append(c.id.in_(select(_DRAFTS.c.sample_id).where(_DRAFTS.c.user_id == drafted_by,
                                                                     _DRAFTS.c.kind == kind.value)))
    free = free_pick(kind, now, *conditions)
    token = secrets.token_urlsafe(16)
    taken = session.connection().execute(
        update(_SAMPLES)
        .where(c.id == free.scalar_subquery())
        .values(leased_by_id=user.id, lease_kind=kind.value, lease_token=token, lease_expires_at=expires)
        .returning(*HEAD_COLUMNS)
    ).first()
    if taken is None:
        return None
    audit.write_rows(session, [audit.row(user.id, action, "sample", taken.id, at=now, kind=kind.value)])
    return Lease(taken.id, token, expires, kind, SampleHead(*taken))


def load_locked(session: Session, sample_id: int) -> Sample:
    """The sample row, locked for the rest of the transaction (PostgreSQL; SQLite is already serialised)."""
    session.flush()  # pending changes first: populate_existing below would otherwise discard them
    sample = session.execute(
        select(Sample).where(Sample.id == sample_id).with_for_update()
        .execution_options(populate_existing=True)
    ).scalar_one_or_none()
    if sample is None:
        raise NotFoundError(f"sample {sample_id} not found")
    return sample


class LeaseState(Protocol):
    """A sample's lease columns: a `Sample` or a Core row holding them."""

    @property
    def id(self) -> int: ...
    @property
    def state(self) -> str: ...
    @property
    def leased_by_id(self) -> int | None: ...
    @property
    def lease_kind(self) -> str | None: ...
    @property
    def lease_token(self) -> str | None: ...
    @property
    def lease_expires_at(self) -> datetime | None: ...


def check_lease(sample: LeaseState, user: Actor, kind: LeaseKind, token: str | None,
                now: datetime | None = None) -> None:
    """Raise unless `user` holds a live lease of `kind` on `sample` (and `token` matches, if given)."""
    now = now or utcnow()
    if sample.leased_by_id != user.id or sample.lease_kind != kind:
        if sample.state != QUEUE_STATE[kind]:
            raise ConflictError(f"sample {sample.id} is '{sample.state}', not in the {kind.value} queue")
        raise PermissionDeniedError(f"you hold no {kind.value} lease on sample {sample.id}; ask for the next task")
    if token is not None and sample.lease_token != token:
        raise PermissionDeniedError(f"lease token does not match your lease on sample {sample.id}; use the token "
                                    "your latest next task or retake returned")
    if sample.lease_expires_at is None or sample.lease_expires_at <= now:
        raise LeaseExpiredError(f"your lease on sample {sample.id} expired; take it again (POST /api/{kind.value}/"
                                f"samples/{sample.id}/lease/retake) or ask for the next task")


def renew(session: Session, user: Actor, sample_id: int, kind: LeaseKind, token: str | None,
          lease_seconds: int) -> Lease:
    sample = load_locked(session, sample_id)
    check_lease(sample, user, kind, token)
    sample.lease_expires_at = utcnow() + timedelta(seconds=lease_seconds)
    return _lease_of(sample)


def retake(session: Session, user: Actor, sample_id: int, kind: LeaseKind, token: str | None,
           lease_seconds: int, now: datetime | None = None, *, in_queue: bool | None = None) -> Lease:
    """Take the lease on `sample_id` again after it lapsed (the server was unreachable, the laptop slept),
    so the work on screen can still be submitted: allowed while the sample is in the queue and nobody else
    holds a live lease on it. The token is kept when the lapsed lease was the caller's own and nobody took
    the sample since; otherwise (released, or another's lapsed lease) a new one is issued. A live own lease
    is renewed. `token` (the one the caller had) is only recorded in the audit row.

    `in_queue`: the caller has decided whether the sample is this queue's work (a blind audit of an accepted label is
    the review queue's: services.review.label_audits.retake); by default, its state is the queue's.

    ConflictError (409) naming why when the sample left the queue or another person holds it now."""
    now = now or utcnow()
    sample = load_locked(session, sample_id)
    if not (sample.state == QUEUE_STATE[kind] if in_queue is None else in_queue):
        raise ConflictError(f"sample {sample_id} is '{sample.state}' now, no longer in the {kind.value} queue")
    live = sample.lease_expires_at is not None and sample.lease_expires_at > now
    mine = sample.leased_by_id == user.id and sample.lease_kind == kind
    if live and not mine:
        raise ConflictError(_taken_by_another(session, user, sample_id, kind, token))
    if not mine or sample.lease_token is None:  # someone's lapsed lease, or a released one: a new lease
        sample.lease_token = secrets.token_urlsafe(16)
    sample.leased_by_id = user.id
    sample.lease_kind = kind.value
    sample.lease_expires_at = now + timedelta(seconds=lease_seconds)
    if not live:
        audit.record(session, user.id, "lease.retake", "sample", sample_id, kind=kind.value,
                     same_token=sample.lease_token == token)
    return _lease_of(sample)


def _taken_by_another(session: Session, user: Actor, sample_id: int, kind: LeaseKind, token: str | None) -> str:
    """Why a retake is refused while another person holds the sample: "your lease had lapsed" only when the caller
    did hold one (a draft of theirs saved under the token they name), else plainly that someone else holds it."""

    held = token is not None and session.execute(select(Draft.id).where(
        Draft.sample_id == sample_id, Draft.kind == kind.value, Draft.user_id == user.id,
        Draft.lease_token == token)).first() is not None
    if held:
        return f"sample {sample_id} was given to someone else while your lease had lapsed"
    return f"sample {sample_id} is leased by someone else now; take the next task instead"


def release(session: Session, user: Actor, sample_id: int, kind: LeaseKind, token: str | None) -> None:
    sample = load_locked(session, sample_id)
    check_lease(sample, user, kind, token)
    clear(sample)
    audit.record(session, user.id, "lease.release", "sample", sample_id, kind=kind.value)


def clear(sample: Sample) -> None:
    sample.leased_by_id = None
    sample.lease_kind = None
    sample.lease_token = None
    sample.lease_expires_at = None


def queue_length(session: Session, kind: LeaseKind, now: datetime | None = None) -> int:
    now = now or utcnow()
    return session.execute(
        select(func.count()).select_from(Sample).where(
            and_(Sample.state == QUEUE_STATE[kind],
                 or_(Sample.lease_expires_at.is_(None), Sample.lease_expires_at <= now)))
    ).scalar_one()
