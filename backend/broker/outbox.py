"""The outbox of the job hand-off: jobs whose task never reached a worker are sent again.

A job row is committed before its task is sent (a worker must find the row), so the send can fail after
the commit (broker down, process killed in between). This pass, run every `outbox_poll_s` by the API's
`CeleryJobQueue`, finds and re-sends:
- queued jobs with `dispatched_at` NULL (their send failed);
- queued jobs sent more than `job_redispatch_after_s` ago (a broker that lost its messages, e.g. a Redis
  restart without persistence);
- running jobs whose row has not changed for twice `job_heartbeat_timeout_s` (their worker died and the
  broker did not deliver the task again: a Redis restart without persistence, a broker folder lost, no
  worker left to recover the embedded broker's held messages).
Tasks claim their job row (services.jobs.jobs.claim), so a task delivered twice runs once.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import ColumnElement, and_, or_, select, update

from backend.db.base import utcnow
from backend.models.enums import JobState
from backend.models.jobs import Job
from backend.settings import Settings

logger = logging.getLogger(__name__)

Send = Callable[[int, str, dict[str, Any]], bool]


def due_condition(settings: Settings, now: datetime) -> ColumnElement[bool]:
    resend_before = now - timedelta(seconds=settings.job_redispatch_after_s)
    dead_before = now - timedelta(seconds=2 * settings.job_heartbeat_timeout_s)
    return or_(
        and_(Job.state == JobState.queued, or_(Job.dispatched_at.is_(None), Job.dispatched_at < resend_before)),
        and_(Job.state == JobState.running, Job.updated_at < dead_before,
             or_(Job.dispatched_at.is_(None), Job.dispatched_at < dead_before)),
    )


def redispatch(session_factory: Any, send: Send, settings: Settings, limit: int = 200) -> int:
    """One outbox pass; returns how many jobs were re-sent. Stops at the first failed send (broker down)."""
    now = utcnow()
    sent = 0
    with session_factory.begin() as session:
        rows = session.execute(
            select(Job.id, Job.kind, Job.payload).where(due_condition(settings, now)).order_by(Job.id).limit(limit)
            .with_for_update(skip_locked=True)
        ).all()
        for job_id, kind, payload in rows:
            if not send(job_id, kind, payload or {}):
                break
            # updated_at kept as it is: it is the heartbeat that lets the new delivery take a dead job over
            session.execute(update(Job).where(Job.id == job_id).values(dispatched_at=now, updated_at=Job.updated_at))
            sent += 1
    return sent
