"""The Celery tasks: thin, named, taking ids; each calls one job service (workers.tasks.fits, training,
inference, rounds, preannotate) that re-loads its rows and returns quietly when there is nothing to do.

Every task is acknowledged late (after it ran) and requeued when its process dies; services claim their
job rows, so a redelivered task records nothing twice, and a delivery for a job that may still run under
another attempt is retried later, never dropped (workers.tasks.recovery, the app's task class). Tasks do
not raise for a sample or a job that fails: the failure is recorded in the database, and a round's canvas
goes on.

Each task imports its job service when it first runs (`# deferred: ...` below): the worker's start-up registers
every task without loading each job's modules (cv2, PIL, the compute core), and tests replace a service's
function on its own module.
"""

from __future__ import annotations

import logging
from typing import Any

from celery import chain, chord

from backend.broker.celery_queue import (
    TASK_EXPORT,
    TASK_FIT,
    TASK_FIT_BATCH,
    TASK_HEURISTIC,
    TASK_PREANNOTATE,
    TASK_PREDICT,
    TASK_REVIEW_QUEUE,
    TASK_ROUND,
    TASK_ROUND_FINISH,
    TASK_ROUND_INFERENCE,
    TASK_TRAIN_HANDSEGNET,
    TASK_TRAIN_MVNET,
)
from backend.models.jobs import Job
from backend.settings import get_settings
from workers.tasks.app import celery_app
from workers.tasks.context import get_context

log = logging.getLogger(__name__)

_SETTINGS = get_settings()
FIT_LIMITS = {"time_limit": _SETTINGS.fit_task_time_limit_s,
              "soft_time_limit": max(1, int(_SETTINGS.fit_task_time_limit_s * 0.9))}


@celery_app.task(name=TASK_FIT, ignore_result=True, **FIT_LIMITS)
def fit(job_ids: int | list[int]) -> dict[str, Any]:
    """Fit one sample or a few sent together (annotators' submissions, single predictions) as one batch."""
    from workers.tasks.fits import run_fit_jobs  # deferred: see the docstring

    ids = [int(job_ids)] if isinstance(job_ids, int) else [int(i) for i in job_ids]
    summary = run_fit_jobs(get_context(), ids)
    summary.raise_for_running_elsewhere()  # retried for those (workers.tasks.recovery)
    return summary.to_dict()


@celery_app.task(name=TASK_FIT_BATCH, **FIT_LIMITS)
def fit_batch(job_ids: list[int] | dict[str, Any], round_job_id: int | None = None) -> dict[str, Any]:
    """Fit several samples, `fit_batch_size` at a time in one optimisation. In a round it follows a
    prediction task, whose result (a dict with `fit_job_ids`) arrives as the first argument."""
    from workers.tasks.fits import run_fit_jobs_batched  # deferred: see the docstring

    ids = job_ids.get("fit_job_ids", []) if isinstance(job_ids, dict) else job_ids
    return run_fit_jobs_batched(get_context(), [int(i) for i in ids], round_job_id=round_job_id)


@celery_app.task(name=TASK_TRAIN_HANDSEGNET)
def train_handsegnet(job_id: int) -> dict[str, Any]:
    """Train HandSegNet on the round's accepted samples (model masks of their fits)."""
    from workers.tasks.training import run_training_job  # deferred: see the docstring

    return run_training_job(get_context(), int(job_id))


@celery_app.task(name=TASK_TRAIN_MVNET)
def train_mvnet(job_id: int) -> dict[str, Any]:
    """Train MVNet on the round's accepted samples (3D keypoints of their fits)."""
    from workers.tasks.training import run_training_job  # deferred: see the docstring

    return run_training_job(get_context(), int(job_id))


@celery_app.task(name=TASK_PREDICT, **FIT_LIMITS)
def predict_batch(job_id: int) -> dict[str, Any]:
    """Predict masks and 3D keypoints for a batch of samples; queue their fits (returned for fit_batch)."""
    from workers.tasks.inference import run_prediction_job  # deferred: see the docstring

    return run_prediction_job(get_context(), int(job_id))


@celery_app.task(name=TASK_PREANNOTATE)
def preannotate(job_id: int) -> dict[str, Any]:
    """Round 0 without clicks: detector -> triangulation -> fit on a project's unlabeled samples -> reviewers."""
    from workers.tasks.preannotate import run_preannotation_job  # deferred: see the docstring

    return run_preannotation_job(get_context(), int(job_id))


@celery_app.task(name=TASK_EXPORT)
def export_freihand(job_id: int) -> dict[str, Any]:
    """The accepted dataset in FreiHAND's layout, zipped into storage (services.exports.export_jobs)."""
    from workers.tasks.export import run_freihand_export_job  # deferred: see the docstring

    return run_freihand_export_job(get_context(), int(job_id))


@celery_app.task(name=TASK_HEURISTIC)
def heuristic(round_job_id: int) -> dict[str, Any] | None:
    """Summarise (and apply where missing) the heuristic verification of the round's fits."""
    from workers.tasks.round_steps import run_heuristic  # deferred: see the docstring

    return run_heuristic(get_context(), int(round_job_id))


@celery_app.task(name=TASK_REVIEW_QUEUE)
def build_review_queue(round_job_id: int) -> dict[str, Any] | None:
    """Queue fitted samples the heuristic did not accept for reviewers, by the paper's policy."""
    from workers.tasks.round_steps import build_review_queue as build  # deferred: see the docstring

    return build(get_context(), int(round_job_id))


@celery_app.task(name=TASK_ROUND_FINISH)
def round_finish(round_job_id: int) -> dict[str, Any] | None:
    """Record the round's counts per stream and model versions; finish its job."""
    from workers.tasks.round_steps import finish_round  # deferred: see the docstring

    return finish_round(get_context(), int(round_job_id))


@celery_app.task(name=TASK_ROUND_INFERENCE, ignore_result=True)
def round_inference(round_job_id: int) -> None:
    """After training: predict + fit every batch (a chord), then heuristic -> review queue -> finish."""
    from workers.tasks.round_steps import plan_inference  # deferred: see the docstring

    plan = plan_inference(get_context(), int(round_job_id))
    if plan is None:
        return
    header = [chain(predict_batch.si(job_id), fit_batch.s(round_job_id=round_job_id))
              for job_id in plan.predict_job_ids]
    header += [fit_batch.si(ids, round_job_id=round_job_id) for ids in plan.fit_batches]
    callback = chain(heuristic.si(round_job_id), build_review_queue.si(round_job_id), round_finish.si(round_job_id))
    if header:
        chord(header, callback).apply_async()
    else:
        callback.apply_async()


@celery_app.task(name=TASK_ROUND, ignore_result=True)
def bootstrap_round(round_job_id: int) -> None:
    """A bootstrap round: train both networks (a chord), then `round_inference`."""
    from workers.tasks.round_steps import start_round  # deferred: see the docstring

    train_job_ids = start_round(get_context(), int(round_job_id))
    if train_job_ids is None:
        return
    if not train_job_ids:
        round_inference.si(round_job_id).apply_async()
        return
    with get_context().session_factory() as session:
        nets = {job_id: (session.get(Job, job_id).payload or {}).get("net") for job_id in train_job_ids}
    header = [(train_mvnet if nets[job_id] == "mvnet" else train_handsegnet).si(job_id) for job_id in train_job_ids]
    chord(header, round_inference.si(round_job_id)).apply_async()
