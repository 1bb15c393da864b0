"""Job rows (state, progress) and the hand-off to whatever runs them.

`JobQueue` is the seam to the workers: the worker issue implements it with Celery. Jobs are handed over
only after the transaction that created them commits (a worker must find the row).
"""

from __future__ import annotations

import logging
from datetime import datetime
from typing import Any, Protocol

from sqlalchemy import insert
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.enums import JobKind, JobState
from backend.models.jobs import Job
from backend.services import audit
from backend.services.errors import ConflictError, InvalidInputError, NotFoundError
from backend.services.transactions import after_commit

logger = logging.getLogger(__name__)

FINAL_STATES = frozenset({JobState.succeeded, JobState.failed, JobState.cancelled})


class JobQueue(Protocol):
    def enqueue(self, job_id: int, kind: str) -> None:
        """Hand a committed job to the workers."""
        ...

    def revoke(self, job_id: int) -> None:
        """Best effort: stop a queued or running job."""
        ...


class DatabaseJobQueue:
    """Leaves jobs as 'queued' rows for workers that poll the database (the default until Celery)."""

    def enqueue(self, job_id: int, kind: str) -> None:
        logger.debug("job %s (%s) queued in the database", job_id, kind)

    def revoke(self, job_id: int) -> None:
        logger.debug("job %s revoked", job_id)


class InMemoryJobQueue:
    """Test double: remembers what was enqueued and revoked."""

    def __init__(self) -> None:
        self.enqueued: list[tuple[int, str]] = []
        self.revoked: list[int] = []

    def enqueue(self, job_id: int, kind: str) -> None:
        self.enqueued.append((job_id, kind))

    def revoke(self, job_id: int) -> None:
        self.revoked.append(job_id)


def create(session: Session, queue: JobQueue, kind: JobKind, *, actor_id: int | None = None,
           sample_id: int | None = None, round_id: int | None = None, payload: dict[str, Any] | None = None) -> Job:
    job = Job(kind=kind, state=JobState.queued, progress=0.0, sample_id=sample_id, round_id=round_id,
              payload=payload or {}, created_by_id=actor_id)
    session.add(job)
    session.flush()
    audit.record(session, actor_id, "job.create", "job", job.id, kind=kind.value, sample_id=sample_id)
    job_id, job_kind = job.id, kind.value
    after_commit(session, lambda: queue.enqueue(job_id, job_kind))
    return job


def insert_row(session: Session, queue: JobQueue, kind: JobKind, audit_rows: list[dict[str, Any]], *,
               actor_id: int | None = None, sample_id: int | None = None, payload: dict[str, Any] | None = None,
               now: datetime | None = None) -> int:
    """Core counterpart of `create` for the annotators' hot path: one INSERT ... RETURNING id; the audit
    row is appended to `audit_rows` for the caller's single audit insert. Handed to `queue` after commit."""
    now = now or utcnow()
    table = Job.__table__
    job_id: int = session.connection().execute(
        insert(table).values(kind=kind.value, state=JobState.queued.value, progress=0.0, message="",
                             sample_id=sample_id, payload=payload or {}, created_by_id=actor_id, created_at=now,
                             updated_at=now).returning(table.c.id)
    ).scalar_one()
    audit_rows.append(audit.row(actor_id, "job.create", "job", job_id, at=now, kind=kind.value, sample_id=sample_id))
    after_commit(session, lambda: queue.enqueue(job_id, kind.value))
    return job_id


def get(session: Session, job_id: int) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise NotFoundError(f"job {job_id} not found")
    return job


def update_progress(session: Session, job_id: int, progress: float, message: str = "",
                    now: datetime | None = None) -> Job:
    """For workers: mark running and set progress in [0, 1]."""
    if not 0.0 <= progress <= 1.0:
        raise InvalidInputError(f"progress must be in [0, 1], not {progress}")
    job = get(session, job_id)
    if JobState(job.state) in FINAL_STATES:
        raise ConflictError(f"job {job_id} is already {job.state}")
    job.state = JobState.running
    job.progress = progress
    job.message = message
    job.updated_at = now or utcnow()
    return job


def finish(session: Session, job_id: int, state: JobState, *, error: str | None = None,
           result: dict[str, Any] | None = None) -> Job:
    if state not in FINAL_STATES:
        raise InvalidInputError(f"'{state}' is not a final job state")
    job = get(session, job_id)
    if JobState(job.state) in FINAL_STATES:
        return job  # idempotent: a retried worker may report twice
    job.state = state
    job.error = error
    job.result = result
    job.finished_at = utcnow()
    if state is JobState.succeeded:
        job.progress = 1.0
    audit.record(session, None, "job.finish", "job", job.id, state=state.value, error=error)
    return job


def cancel(session: Session, queue: JobQueue, job_id: int, actor_id: int | None) -> Job:
    job = get(session, job_id)
    if JobState(job.state) in FINAL_STATES:
        raise ConflictError(f"job {job_id} is already {job.state}")
    job.state = JobState.cancelled
    job.finished_at = utcnow()
    audit.record(session, actor_id, "job.cancel", "job", job.id)
    after_commit(session, lambda: queue.revoke(job_id))
    return job
