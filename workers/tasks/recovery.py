"""The base class of every handloop task: a delivery for a job that runs under another attempt comes back.

A task's claim (services.jobs.jobs.claim) raises JobStillRunningError when its job is 'running' under an attempt
that may be alive (its heartbeat is recent and its process cannot be seen to be gone). Acknowledging that
delivery would lose the job if the attempt is in fact dead (a worker killed just after a heartbeat, its
message delivered again at once): the task is retried instead, after the time left until the heartbeat
would be stale, as often as it takes, until the job is final (the retry then returns quietly) or the
retry takes it over. A retry keeps the task's id, arguments, chord and callbacks. Set as the worker app's
`task_cls` (workers.tasks.app), so that every task gets this without doing anything.
"""

from __future__ import annotations

import logging
from typing import Any

from celery import Task

from backend.services.jobs.jobs import JobStillRunningError

log = logging.getLogger(__name__)


class JobTask(Task):
    # No limit on these retries: each one waits for a heartbeat to age, and ends when the job is final or taken
    # over (a job that kills every worker fails after JOB_MAX_ATTEMPTS starts).
    max_retries = None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        try:
            return super().__call__(*args, **kwargs)
        except JobStillRunningError as exc:
            if self.request.called_directly or self.request.is_eager:
                raise  # no broker to come back through: the caller decides
            log.info("%s[%s]: %s", self.name, self.request.id, exc)
            raise self.retry(exc=exc, countdown=self.countdown_s(exc.retry_after_s)) from exc

    def countdown_s(self, retry_after_s: float) -> float:
        """`retry_after_s`, kept under half of Redis's visibility timeout: a message held longer than that is
        delivered again while it waits, and every copy would come back."""
        visibility_s = (self.app.conf.broker_transport_options or {}).get("visibility_timeout")
        return min(retry_after_s, visibility_s / 2) if visibility_s else retry_after_s
