"""Progress of running jobs, written to their rows (the UI reads it there) at most every few seconds.

Each write is also the job's heartbeat (its `updated_at`): a job whose row stops changing belongs to a
dead worker (services.jobs.jobs.claim, broker.outbox). A job cancelled meanwhile makes the write fail
with ConflictError; the reporter then drops it, and raises `JobCancelledError` once every job it reports for
is gone, so the work stops.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable

from backend.services.errors import ConflictError, NotFoundError
from backend.services.jobs import jobs
from workers.tasks import round_progress
from workers.tasks.context import WorkerContext

log = logging.getLogger(__name__)


class JobCancelledError(Exception):
    """Every job this work was for has been cancelled (or deleted)."""


class ProgressReporter:
    """Reports one fraction for a set of jobs, optionally mapped into a span of a parent (round) job.

    Args:
        ctx: the worker context.
        job_ids: the jobs doing this work.
        parent: (job id, start, end): also set the parent's progress to start + fraction (end - start).
        heartbeat_of: a job (the round) kept alive by each write, its progress left alone.
        round_of: a round job whose progress is recomputed from its phases after each write (its heartbeat too,
            workers.tasks.round_progress).
        interval_s: least time between writes (capped below the heartbeat timeout).
    """

    def __init__(self, ctx: WorkerContext, job_ids: Iterable[int], *, parent: tuple[int, float, float] | None = None,
                 heartbeat_of: int | None = None, round_of: int | None = None, interval_s: float = 2.0) -> None:
        self.ctx = ctx
        self.live = list(dict.fromkeys(job_ids))
        self.parent = parent
        self.heartbeat_of = heartbeat_of
        self.round_of = round_of
        self.interval_s = min(interval_s, ctx.settings.job_heartbeat_timeout_s / 4)
        self._last = 0.0

    def _anchors(self) -> list[int]:
        """The parent rows this reporter writes besides its own jobs, in the order they are locked."""
        ids = [self.round_of, self.heartbeat_of, self.parent[0] if self.parent is not None else None]
        return list(dict.fromkeys(i for i in ids if i is not None))

    def drop(self, job_id: int) -> None:
        if job_id in self.live:
            self.live.remove(job_id)

    def __call__(self, fraction: float, message: str = "", *, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last < self.interval_s:
            return
        self._last = now
        fraction = min(1.0, max(0.0, float(fraction)))
        cancelled: list[int] = []
        with self.ctx.session_factory.begin() as session:
            # Lock order: the round (or other parent) before its children, as every other writer does
            # (round_progress.lock, rounds.cancel): a heartbeat written after the children's rows could deadlock
            # on PostgreSQL with a cancel that holds the round and waits for a child.
            for anchor in self._anchors():
                round_progress.lock(session, anchor)
            for job_id in self.live:
                try:
                    jobs.update_progress(session, job_id, fraction, message[:500])
                except (ConflictError, NotFoundError):
                    cancelled.append(job_id)
            if self.heartbeat_of is not None:
                jobs.touch(session, self.heartbeat_of)
            if self.round_of is not None:
                session.flush()  # the phases read the rows just written
                round_progress.refresh(session, self.round_of, self.ctx.settings)
            if self.parent is not None:
                parent_id, start, end = self.parent
                try:
                    jobs.update_progress(session, parent_id, start + fraction * (end - start), message[:500])
                except (ConflictError, NotFoundError):
                    self.parent = None
                    if not self.live:
                        cancelled.append(parent_id)
        for job_id in cancelled:
            self.drop(job_id)
        if cancelled and not self.live:
            raise JobCancelledError(f"job(s) {cancelled} cancelled")
