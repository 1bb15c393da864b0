"""The Celery tasks: thin, named, taking ids; each calls one job service (workers.tasks.fits, training,
inference, rounds) that re-loads its rows and returns quietly when there is nothing to do.

Every task is acknowledged late (after it ran) and requeued when its process dies; services claim their
job rows, so a redelivered task records nothing twice. Tasks do not raise for a sample or a job that
fails: the failure is recorded in the database, and a round's canvas goes on.
"""

from __future__ import annotations

import logging
from typing import Any

from backend.services.celery_queue import TASK_FIT, TASK_FIT_BATCH
from backend.settings import get_settings
from workers.tasks.app import celery_app
from workers.tasks.context import get_context

log = logging.getLogger(__name__)

_SETTINGS = get_settings()
FIT_LIMITS = {"time_limit": _SETTINGS.fit_task_time_limit_s,
              "soft_time_limit": max(1, int(_SETTINGS.fit_task_time_limit_s * 0.9))}


@celery_app.task(name=TASK_FIT, ignore_result=True, **FIT_LIMITS)
def fit(job_id: int) -> dict[str, Any]:
    """Fit one sample (an annotator's submission, or a single prediction)."""
    from workers.tasks.fits import run_fit_jobs

    return run_fit_jobs(get_context(), [int(job_id)]).to_dict()


@celery_app.task(name=TASK_FIT_BATCH, **FIT_LIMITS)
def fit_batch(job_ids: list[int] | dict[str, Any], round_job_id: int | None = None,
              progress_span: tuple[float, float] | None = None) -> dict[str, Any]:
    """Fit several samples as one batch. In a round it follows a prediction task, whose result (a dict
    with `fit_job_ids`) arrives as the first argument."""
    from workers.tasks.fits import run_fit_jobs

    ids = job_ids.get("fit_job_ids", []) if isinstance(job_ids, dict) else job_ids
    parent = (int(round_job_id), *progress_span) if round_job_id is not None and progress_span else None
    return run_fit_jobs(get_context(), [int(i) for i in ids], parent=parent).to_dict()  # type: ignore[arg-type]
