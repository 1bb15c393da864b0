"""Annotator submissions: clicks and mask corrections, idempotent on the client's submission id; each
new submission queues a fit.

The annotators' hot path, so written with Core statements on the session's connection (no ORM objects).
On PostgreSQL, a click-only submission from the route is first tried as one statement in autocommit, the
checks as its gate (backend.db.statements.submit_statement.SUBMIT_ALONE: one round trip). The checked path, taken
otherwise and whenever that statement wrote nothing: lock the sample (with its views and any submission
already stored under this client id, in the same statement), check in Python, then, on PostgreSQL, one
statement writes the job, the submission, all clicks, the sample's new state, the audit rows and the drafts'
deletion (two round trips in all); SQLite runs those writes as separate statements (in-process: no round
trips to save).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import func, insert, select, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.db.statements import submit_statement
from backend.models.capture import Sample, View
from backend.models.enums import JobKind, LeaseKind, MaskKind, SampleState, Visibility
from backend.models.labels import Click, Mask, Submission
from backend.schemas.tasks import SubmissionCreate
from backend.services import audit
from backend.services.accounts.users import Actor
from backend.services.captures.masks import encode_png
from backend.services.captures.state_machine import check_path
from backend.services.captures.storage import Storage
from backend.services.errors import (
    ConflictError,
    DomainError,
    InvalidInputError,
    NotFoundError,
    ServiceUnavailableError,
)
from backend.services.jobs import jobs
from backend.services.leases import annotation_flags, drafts, queues
from backend.services.leases.annotation_input import check_clicks, check_masks
from backend.services.transactions import after_commit

_SAMPLES = Sample.__table__
_VIEWS = View.__table__
_SUBMISSIONS = Submission.__table__
_CLICKS = Click.__table__


@dataclass(frozen=True, slots=True)
class SubmissionInfo:
    id: int
    client_id: str
    sample_id: int
    user_id: int
    n_clicks: int
    n_masks: int
    fit_job_id: int | None
    created_at: datetime


@dataclass(frozen=True)
class SubmitResult:
    submission: SubmissionInfo
    duplicate: bool


def _existing(session: Session, client_id: str, user: Actor, sample_id: int) -> SubmissionInfo | None:
    """The committed submission under `client_id` (a resubmission), or None; ConflictError if that id was
    used for another sample or user."""
    c = _SUBMISSIONS.c
    found = session.connection().execute(
        select(c.id, c.client_id, c.sample_id, c.user_id, c.n_clicks, c.n_masks, c.fit_job_id, c.created_at)
        .where(c.client_id == client_id)
    ).first()
    if found is None:
        return None
    info = SubmissionInfo(*found)
    if info.sample_id != sample_id or info.user_id != user.id:
        raise ConflictError(f"submission id {client_id!r} was already used for another sample or user")
    return info


def _lock_with_views(session: Session, sample_id: int, client_id: str) -> list[Any]:
    """The sample row locked for the rest of the transaction (PostgreSQL: FOR UPDATE OF samples; SQLite is
    serialised by BEGIN IMMEDIATE), one result row per view, and the id of a submission already stored under
    `client_id` (seen as of this statement's snapshot)."""
    s, v = _SAMPLES.c, _VIEWS.c
    existing = select(_SUBMISSIONS.c.id).where(_SUBMISSIONS.c.client_id == client_id).scalar_subquery()
    return session.connection().execute(
        select(s.id, s.state, s.leased_by_id, s.lease_kind, s.lease_token, s.lease_expires_at,
               existing.label("existing_id"), v.id.label("view_id"), v.width.label("view_width"),
               v.height.label("view_height"))
        .select_from(_SAMPLES.outerjoin(_VIEWS, v.sample_id == s.id))
        .where(s.id == sample_id)
        .with_for_update(of=_SAMPLES)
    ).all()


def _insert_submission(session: Session, values: dict[str, Any]) -> int | None:
    """INSERT ... ON CONFLICT (client_id) DO NOTHING RETURNING id: None when a concurrent request committed
    a submission under the same client id after our lock statement's snapshot (the unique constraint decides,
    not a racy pre-select)."""
    conn = session.connection()
    dialect = postgresql if conn.dialect.name == "postgresql" else sqlite
    return conn.execute(
        dialect.insert(_SUBMISSIONS).values(**values).on_conflict_do_nothing(index_elements=["client_id"])
        .returning(_SUBMISSIONS.c.id)
    ).scalar_one_or_none()


def _insert_clicks(session: Session, body: SubmissionCreate, submission_id: int, sample_id: int, user_id: int,
                   now: datetime) -> None:
    # SQLite: the driver's executemany (a C loop over one prepared statement).
    session.connection().execute(insert(_CLICKS), [
        {"submission_id": submission_id, "sample_id": sample_id, "view_id": c.view_id, "keypoint": c.keypoint,
         "x_px": c.x, "y_px": c.y, "visibility": Visibility(c.visibility).value, "from_proposal": c.from_proposal,
         "user_id": user_id,
         "time_spent_s": body.time_spent_s, "created_at": now}
        for c in body.clicks
    ])


def submit(session: Session, queue: jobs.JobQueue, storage: Storage, user: Actor, sample_id: int,
           body: SubmissionCreate, max_clicks: int, *, sole_statement: bool = False) -> SubmitResult:
    """Store a submission and queue its fit, or return the one stored under its client id (duplicate).

    `sole_statement`: the caller's request writes nothing else. On PostgreSQL, when the session has not begun
    a transaction, a click-only submission is then tried as one statement in autocommit
    (submit_statement.SUBMIT_ALONE); when one of its checks fails it wrote nothing, and the checked path
    below (lock, checks, writes, in a transaction) answers, naming the error."""
    if sole_statement:
        written = _submit_alone(session, queue, user, sample_id, body, max_clicks)
        if written is not None:
            return written
    rows = _lock_with_views(session, sample_id, body.submission_id)
    if not rows:
        found = _existing(session, body.submission_id, user, sample_id)  # same precedence as before: 409 first
        if found is not None:
            return SubmitResult(found, duplicate=True)
        raise NotFoundError(f"sample {sample_id} not found")
    sample = rows[0]
    if sample.existing_id is not None:
        found = _existing(session, body.submission_id, user, sample_id)
        assert found is not None  # submissions are never deleted while their sample exists
        return SubmitResult(found, duplicate=True)
    try:
        queues.check_lease(sample, user, LeaseKind.annotate, body.lease_token)
    except DomainError:
        # A concurrent twin of this request may have committed while we waited for the lock (it cleared the
        # lease); this statement runs with a fresh snapshot on PostgreSQL, so it sees the twin.
        found = _existing(session, body.submission_id, user, sample_id)
        if found is not None:
            return SubmitResult(found, duplicate=True)
        raise
    check_path(sample_id, sample.state, SampleState.annotated, SampleState.fitting)
    if len(body.clicks) > max_clicks:
        raise InvalidInputError(f"{len(body.clicks)} clicks in one submission; at most {max_clicks}")

    views = {r.view_id: (r.view_width, r.view_height) for r in rows if r.view_id is not None}
    check_clicks(views, body.clicks, sample_id)
    _check_no_hand_views(views, body, sample_id)
    decoded = check_masks(views, body.masks, sample_id)

    now = utcnow()
    payload = {"client_submission_id": body.submission_id, "source": "annotation"}
    if session.connection().dialect.name == "postgresql":
        queue.ensure_available()  # before anything is written: an unreachable broker is a 503 that writes nothing
        job_id, submission_id = submit_statement.write(
            session.connection(), sample_id=sample_id, user_id=user.id, client_id=body.submission_id,
            from_state=SampleState(sample.state).value, time_spent_s=body.time_spent_s, clicks=body.clicks,
            n_masks=len(decoded), payload=payload, now=now)
        if submission_id is None:  # raising rolls back the job too: a failed request writes nothing
            raise ConflictError(f"submission id {body.submission_id!r} was already used for another sample or user")
        after_commit(session, lambda: queue.enqueue(job_id, JobKind.fit.value))
    else:
        job_id, submission_id = _write_separately(session, queue, user, sample_id, sample.state, body, len(decoded),
                                                  payload, now)
    if decoded:
        _write_masks(session, user, body.submission_id, submission_id, decoded, storage, now)
    annotation_flags.record_no_hand_views(session, user.id, sample_id, submission_id, body.no_hand_views, now)
    info = SubmissionInfo(submission_id, body.submission_id, sample_id, user.id, len(body.clicks), len(decoded),
                          job_id, now)
    return SubmitResult(info, duplicate=False)


def _check_no_hand_views(views: dict[int, tuple[int, int]], body: SubmissionCreate, sample_id: int) -> None:
    """Views marked 'no hand here' are views of the sample, each once, with no point placed in them."""
    seen: set[int] = set()
    for i, view_id in enumerate(body.no_hand_views):
        if view_id not in views:
            raise InvalidInputError(f"no_hand_views[{i}]: view {view_id} is not a view of sample {sample_id}")
        if view_id in seen:
            raise InvalidInputError(f"no_hand_views[{i}]: view {view_id} given twice")
        seen.add(view_id)
    for i, c in enumerate(body.clicks):
        if c.view_id in seen and c.visibility != Visibility.not_annotated:
            raise InvalidInputError(f"clicks[{i}]: a point is placed in view {c.view_id}, which is marked 'no hand "
                                    "here'; clear the point or the mark")


def _submit_alone(session: Session, queue: jobs.JobQueue, user: Actor, sample_id: int, body: SubmissionCreate,
                  max_clicks: int) -> SubmitResult | None:
    """PostgreSQL: the submission in one statement, in autocommit; None when it is not tried (SQLite, a
    transaction already begun, masks, checks that need no database failing, the broker unreachable) or wrote
    nothing. Whatever makes it step aside, the checked path gives the answer it gave before, with the same
    precedence of errors."""
    if (session.get_bind().dialect.name != "postgresql" or session.in_transaction() or body.masks
            or body.no_hand_views
            or len(body.clicks) > max_clicks
            or len({(c.view_id, c.keypoint) for c in body.clicks}) != len(body.clicks)):
        return None
    try:
        queue.ensure_available()  # before anything is written: an unreachable broker is a 503 that writes nothing
    except ServiceUnavailableError:
        return None  # the checked path raises it again, after the checks that came first there
    now = utcnow()
    conn = session.connection(execution_options={"isolation_level": "AUTOCOMMIT"})
    try:
        written = submit_statement.write_alone(
            conn, sample_id=sample_id, user_id=user.id, client_id=body.submission_id, lease_token=body.lease_token,
            time_spent_s=body.time_spent_s, clicks=body.clicks,
            payload={"client_submission_id": body.submission_id, "source": "annotation"}, now=now)
    except IntegrityError:  # the client id was taken meanwhile: the statement wrote nothing
        written = None
    if written is None:
        session.rollback()  # the autocommit connection back to the pool: the checked path runs in a transaction
        return None
    job_id, submission_id = written
    after_commit(session, lambda: queue.enqueue(job_id, JobKind.fit.value))
    return SubmitResult(SubmissionInfo(submission_id, body.submission_id, sample_id, user.id, len(body.clicks), 0,
                                       job_id, now), duplicate=False)


def _write_separately(session: Session, queue: jobs.JobQueue, user: Actor, sample_id: int, from_state: str,
                      body: SubmissionCreate, n_masks: int, payload: dict[str, Any], now: datetime) -> tuple[int, int]:
    """SQLite: the writes of submit_statement as separate statements (in-process, so no round trips to save);
    returns (fit job id, submission id)."""
    audit_rows: list[dict[str, Any]] = []
    # The fit job first, so the submission row is written once, already pointing at it.
    # (the worker finds the submission through submissions.fit_job_id)
    job_id = jobs.insert_row(session, queue, JobKind.fit, audit_rows, actor_id=user.id, sample_id=sample_id,
                             payload=payload, now=now)
    submission_id = _insert_submission(session, {
        "fit_job_id": job_id, "client_id": body.submission_id, "sample_id": sample_id, "user_id": user.id,
        "time_spent_s": body.time_spent_s, "n_clicks": len(body.clicks), "n_masks": n_masks, "created_at": now})
    if submission_id is None:  # raising rolls back the job too: a failed request writes nothing
        raise ConflictError(f"submission id {body.submission_id!r} was already used for another sample or user")
    if body.clicks:
        _insert_clicks(session, body, submission_id, sample_id, user.id, now)
    # needs_annotation -> annotated -> fitting (checked above) and the lease cleared, in one UPDATE.
    session.connection().execute(
        update(_SAMPLES).where(_SAMPLES.c.id == sample_id)
        .values(state=SampleState.fitting.value, leased_by_id=None, lease_kind=None, lease_token=None,
                lease_expires_at=None))
    audit_rows += [
        audit.row(user.id, "sample.state", "sample", sample_id, at=now, **{
            "from": SampleState(from_state).value, "to": SampleState.annotated.value,
            "reason": f"submission {submission_id}"}),
        audit.row(user.id, "sample.state", "sample", sample_id, at=now, **{
            "from": SampleState.annotated.value, "to": SampleState.fitting.value, "reason": "fit queued"}),
        audit.row(user.id, "submission.create", "sample", sample_id, at=now, submission_id=submission_id,
                  client_id=body.submission_id, clicks=len(body.clicks), masks=n_masks),
    ]
    audit.write_rows(session, audit_rows)
    drafts.delete_for_sample(session, sample_id, LeaseKind.annotate)  # submitted: the work in progress is done
    return job_id, submission_id


def _write_masks(session: Session, user: Actor, client_id: str, submission_id: int, decoded: list[Any],
                 storage: Storage, now: datetime) -> None:
    """The corrected masks as new versions of their views' masks."""
    versions = dict(session.execute(
        select(Mask.view_id, func.max(Mask.version)).where(Mask.view_id.in_([v for v, _ in decoded]))
        .group_by(Mask.view_id)).all())
    for view_id, mask in decoded:
        # Written before commit under a key unique to this submission: a rollback leaves at most an
        # unreferenced file, never a row pointing at nothing.
        key = f"masks/corrected/{view_id}/{client_id}.png"
        storage.put_bytes(key, encode_png(mask))
        session.add(Mask(view_id=view_id, kind=MaskKind.corrected, version=(versions.get(view_id) or 0) + 1,
                         storage_key=key, submission_id=submission_id, created_by_id=user.id, created_at=now))
