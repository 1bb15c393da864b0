"""Job rows (state, progress) and the hand-off to whatever runs them.

`JobQueue` is the seam to the workers (backend.broker.celery_queue.CeleryJobQueue in production). Jobs
are handed over only after the transaction that created them commits (a worker must find the row); the
queue's availability is checked before anything is written, so an unreachable broker answers 503 and
writes nothing, and a hand-off that still fails after the commit leaves `dispatched_at` NULL for the
outbox to re-send (backend.broker.outbox).
"""

from __future__ import annotations

import logging
from datetime import datetime
from typing import Any, Protocol

from sqlalchemy import insert, select, update
from sqlalchemy.orm import Session

from backend.broker import worker_processes
from backend.db.base import utcnow
from backend.models.enums import JobKind, JobState
from backend.models.jobs import Job
from backend.services import audit
from backend.services.errors import ConflictError, InvalidInputError, NotFoundError, ServiceUnavailableError
from backend.services.jobs import fit_samples, round_failure
from backend.services.leases import queues
from backend.services.transactions import after_commit

logger = logging.getLogger(__name__)

FINAL_STATES = frozenset({JobState.succeeded, JobState.failed, JobState.cancelled})


class JobQueue(Protocol):
    def ensure_available(self) -> None:
        """Raise ServiceUnavailableError when jobs cannot be handed over now (called before writing)."""
        ...

    def enqueue(self, job_id: int, kind: str) -> None:
        """Hand a committed job to the workers. Never raises: a failed hand-off is left to the outbox."""
        ...

    def revoke(self, job_id: int) -> None:
        """Best effort: stop a queued or running job (workers also see the 'cancelled' row)."""
        ...


class DatabaseJobQueue:
    """Leaves jobs as 'queued' rows (for tools that poll the database); hands nothing to a broker."""

    def ensure_available(self) -> None:
        pass

    def enqueue(self, job_id: int, kind: str) -> None:
        logger.debug("job %s (%s) queued in the database", job_id, kind)

    def revoke(self, job_id: int) -> None:
        logger.debug("job %s revoked", job_id)


class InMemoryJobQueue:
    """Test double: remembers what was enqueued and revoked; `available = False` acts as a broker outage."""

    def __init__(self) -> None:
        self.enqueued: list[tuple[int, str]] = []
        self.revoked: list[int] = []
        self.available = True

    def ensure_available(self) -> None:
        if not self.available:
            raise ServiceUnavailableError("the job queue is unavailable; nothing was written, retry later")

    def enqueue(self, job_id: int, kind: str) -> None:
        self.enqueued.append((job_id, kind))

    def revoke(self, job_id: int) -> None:
        self.revoked.append(job_id)


def create(session: Session, queue: JobQueue, kind: JobKind, *, actor_id: int | None = None,
           sample_id: int | None = None, round_id: int | None = None, payload: dict[str, Any] | None = None,
           enqueue: bool = True) -> Job:
    """A queued job, handed to `queue` after commit. `enqueue=False`: the caller runs it itself (a round's
    steps, sent as one Celery canvas), so it is marked dispatched and the outbox leaves it alone."""
    if enqueue:
        queue.ensure_available()
    job = Job(kind=kind, state=JobState.queued, progress=0.0, sample_id=sample_id, round_id=round_id,
              payload=payload or {}, created_by_id=actor_id, dispatched_at=utcnow())
    session.add(job)
    session.flush()
    audit.record(session, actor_id, "job.create", "job", job.id, kind=kind.value, sample_id=sample_id)
    job_id, job_kind = job.id, kind.value
    if enqueue:
        after_commit(session, lambda: queue.enqueue(job_id, job_kind))
    return job


def insert_row(session: Session, queue: JobQueue, kind: JobKind, audit_rows: list[dict[str, Any]], *,
               actor_id: int | None = None, sample_id: int | None = None, payload: dict[str, Any] | None = None,
               now: datetime | None = None) -> int:
    """Core counterpart of `create` for the annotators' hot path: one INSERT ... RETURNING id; the audit
    row is appended to `audit_rows` for the caller's single audit insert. Handed to `queue` after commit."""
    queue.ensure_available()
    now = now or utcnow()
    table = Job.__table__
    job_id: int = session.connection().execute(
        insert(table).values(kind=kind.value, state=JobState.queued.value, progress=0.0, message="",
                             sample_id=sample_id, payload=payload or {}, created_by_id=actor_id, created_at=now,
                             updated_at=now, dispatched_at=now, attempts=0).returning(table.c.id)
    ).scalar_one()
    audit_rows.append(audit.row(actor_id, "job.create", "job", job_id, at=now, kind=kind.value, sample_id=sample_id))
    after_commit(session, lambda: queue.enqueue(job_id, kind.value))
    return job_id


def get(session: Session, job_id: int) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise NotFoundError(f"job {job_id} not found")
    return job


class JobStillRunningError(Exception):
    """A delivery for jobs that run under another attempt which may be alive: it must come back later
    (workers.tasks.recovery retries the task after `retry_after_s`), never be acknowledged and forgotten,
    since that attempt may be dead without its heartbeat showing it yet."""

    def __init__(self, job_ids: list[int], retry_after_s: float, workers: list[str | None]) -> None:
        self.job_ids = job_ids
        self.retry_after_s = retry_after_s
        self.workers = workers
        super().__init__(f"job(s) {job_ids} running under another attempt ({', '.join(map(str, workers))}); "
                         f"delivery retried in {retry_after_s:.0f} s")

    @classmethod
    def merge(cls, errors: list[JobStillRunningError]) -> JobStillRunningError:
        """One error for a batch: retried when the first of its jobs may be taken over."""
        return cls([i for e in errors for i in e.job_ids], min(e.retry_after_s for e in errors),
                   [w for e in errors for w in e.workers])


def claim(session: Session, job_id: int, worker: str, stale_after_s: float, now: datetime | None = None, *,
          max_attempts: int | None = None, process: str | None = None) -> Job | None:
    """For workers: start a job, or take over one whose worker died. Idempotent under redelivery.

    Returns None when there is nothing to do: the job is gone or final. A 'running' job is taken over when
    its attempt is dead: its process (`worker_process`, see backend.broker.worker_processes) is gone, which a
    claimant on the same machine sees at once, or its row has not changed for `stale_after_s` (a worker on
    another machine, or a hung one). Otherwise the attempt may be alive and JobStillRunningError is raised:
    the delivery must come back after the error's `retry_after_s` (the time left until the heartbeat would
    be stale), until the job is final or taken over. A job started `max_attempts` times already fails
    instead of being taken over (a job that kills or crashes every worker must not come back forever), and
    a fit's sample goes back to the annotators. `process`: the claimant's identity, recorded for the next.
    """
    now = now or utcnow()
    job = session.execute(select(Job).where(Job.id == job_id).with_for_update()
                          .execution_options(populate_existing=True)).scalar_one_or_none()
    if job is None or JobState(job.state) in FINAL_STATES:
        return None
    reason = ""
    if job.state == JobState.running:
        age_s = (now - job.updated_at).total_seconds()
        if worker_processes.is_gone(job.worker_process):
            reason = f"its process is gone, heartbeat {age_s:.1f} s old"
        elif age_s >= stale_after_s:
            reason = f"no heartbeat for {age_s:.1f} s"
        else:
            retry_after_s = max(1.0, stale_after_s - age_s + 1.0)
            logger.info("job %s is running under another attempt (%s, heartbeat %.1f s old); delivery retried in "
                        "%.0f s", job_id, job.worker, age_s, retry_after_s)
            raise JobStillRunningError([job_id], retry_after_s, [job.worker])
    if max_attempts is not None and (job.attempts or 0) >= max_attempts:
        error = f"gave up after {job.attempts} attempts (the last by {job.worker}); see the worker logs"
        logger.warning("job %s: %s", job_id, error)
        if job.kind == JobKind.fit and job.sample_id is not None:
            sample = queues.load_locked(session, job.sample_id)  # the sample before the job, as records does
            finish(session, job.id, JobState.failed, error=error)
            fit_samples.release_failed_fit(session, sample, error)
        else:
            finish(session, job.id, JobState.failed, error=error)
        return None
    if reason:
        logger.warning("job %s: attempt %s by %s is dead (%s); taken over by %s", job_id, job.attempts, job.worker,
                       reason, worker)
    job.state = JobState.running
    job.attempts = (job.attempts or 0) + 1
    job.worker = worker[:200]
    job.worker_process = process
    job.updated_at = now
    job.started_at = now  # this attempt's start: a taken-over job's duration counts the attempt that ended it
    job.message = f"taken over by {worker} (attempt {job.attempts})" if reason else f"started by {worker}"
    audit.record(session, None, "job.start", "job", job.id, attempt=job.attempts, worker=worker)
    return job


def touch(session: Session, job_id: int, now: datetime | None = None) -> None:
    """Heartbeat of a running job whose progress someone else reports (a round while its batches run)."""
    session.execute(update(Job).where(Job.id == job_id, Job.state == JobState.running)
                    .values(updated_at=now or utcnow()))


def is_final(session: Session, job_id: int) -> bool:
    state = session.execute(select(Job.state).where(Job.id == job_id)).scalar_one_or_none()
    return state is None or JobState(state) in FINAL_STATES


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
    job.message = ""  # the last progress message ("predicting 0/16") no longer says what the job is doing
    if state is JobState.succeeded:
        job.progress = 1.0
    audit.record(session, None, "job.finish", "job", job.id, state=state.value, error=error)
    if state is JobState.failed and job.kind == JobKind.round:
        round_failure.reopen_previous(session, job, error)  # the round table as it was before the launch
    return job


def cancel(session: Session, queue: JobQueue, job_id: int, actor_id: int | None) -> Job:
    job = get(session, job_id)
    if JobState(job.state) in FINAL_STATES:
        raise ConflictError(f"job {job_id} is already {job.state}")
    job.state = JobState.cancelled
    job.finished_at = utcnow()
    job.message = ""
    audit.record(session, actor_id, "job.cancel", "job", job.id)
    if job.kind == JobKind.fit and job.sample_id is not None:
        fit_samples.release_cancelled_fit(session, job.sample_id, job.id)
    after_commit(session, lambda: queue.revoke(job_id))
    return job
