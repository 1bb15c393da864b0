"""Prediction jobs of a round: HandSegNet masks and MVNet 3D keypoints for samples not yet in the dataset,
recorded per sample (workers.tasks.records.record_prediction); samples that may be refitted ('unlabeled',
'fitted') get a fit job from the prediction, run by the fit task that follows in the round's canvas.

A redelivered job skips the samples it already recorded (predictions are unique per job and sample).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np
from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy import select

from backend.models.capture import Sample
from backend.models.enums import JobState, SampleState
from backend.models.fits import Prediction
from backend.models.jobs import Job
from backend.services.errors import DomainError
from backend.services.jobs import jobs
from workers.tasks import records, round_progress
from workers.tasks.context import WorkerContext
from workers.tasks.inputs import InputError, load_frames, rig_of
from workers.tasks.progress import JobCancelledError, ProgressReporter
from workers.tasks.training import ROUND_HANDEDNESS, checkpoint_of, detection_cache
from workers.tasks.working_inputs import WorkingRig, probabilities_at_full_resolution, working_frames, working_rig

log = logging.getLogger(__name__)

REFITTABLE = (SampleState.unlabeled.value, SampleState.fitted.value)
PREDICTABLE = (*REFITTABLE, SampleState.needs_annotation.value)


def load_net(ctx: WorkerContext, version: str, kind: str) -> Any:
    """A network by version name, loaded once per process (and again when its file changes)."""
    # deferred: torch only where a job predicts: fits (touch_round) and the round's steps import this module
    from workers.nets.checkpoints import load_model
    from workers.nets.train import default_device

    path = checkpoint_of(ctx, version)
    if not path.is_file():
        raise InputError(f"model {version!r} has no checkpoint at {path}")
    stamp = path.stat().st_mtime_ns
    return ctx.cached(("net", str(path), stamp), lambda: load_model(path, kind, device=default_device())[0])


def run_prediction_job(ctx: WorkerContext, job_id: int) -> dict[str, Any]:
    """Claim a predict job (payload: sample_ids, mvnet and handsegnet versions, round_job_id), predict and
    record; returns {"fit_job_ids": [...], ...} for the fit task chained after it."""
    with ctx.session_factory.begin() as session:
        job = ctx.claim(session, job_id)
        if job is None:
            return {"job_id": job_id, "skipped": True, "fit_job_ids": _fit_jobs_of(ctx, job_id)}
        payload = dict(job.payload or {})
        round_id = job.round_id
    round_job_id = payload.get("round_job_id")
    sample_ids = [int(s) for s in payload.get("sample_ids", [])]
    try:
        mvnet = load_net(ctx, payload["mvnet_version"], "mvnet")
        handsegnet = load_net(ctx, payload["handsegnet_version"], "handsegnet") if payload.get(
            "handsegnet_version") else None
        with ctx.session_factory() as session:
            done = set(session.execute(select(Prediction.sample_id).where(Prediction.job_id == job_id)).scalars())
            frames = load_frames(ctx, session, [s for s in sample_ids if s not in done])
            todo = [f for f in frames.values() if f.state in PREDICTABLE]
            wrig = working_rig(session, rig_of(ctx, session, todo[0].project_id)) if todo else None
        reporter = ProgressReporter(ctx, [job_id], round_of=int(round_job_id) if round_job_id else None)
        summary = {"predicted": 0, "not_localised": 0, "skipped": len(sample_ids) - len(todo)}
        chunk = 4
        for start in range(0, len(todo), chunk):
            reporter(start / max(1, len(todo)), f"predicting {start}/{len(todo)} samples")
            part = working_frames(ctx, todo[start:start + chunk], wrig)  # the networks read working copies
            out = _predict(ctx, mvnet, handsegnet, part, wrig)
            for i, frame in enumerate(part):
                _record(ctx, job_id, round_id, frame, out, i, payload, summary,
                        mask_source="handsegnet" if handsegnet is not None else "chroma_key")
            # Green-screen frames where HandSegNet found no hand (early rounds: little training data) are
            # localised by their chroma-key masks instead; their fits then use those masks.
            lost = [f for i, f in enumerate(part) if handsegnet is not None and f.frame.mask_paths
                    and not np.isfinite(out.keypoints.keypoints_3d[i]).all()]
            if lost:
                fallback = _predict(ctx, mvnet, None, lost, wrig)
                summary["not_localised"] -= len(lost)
                for i, frame in enumerate(lost):
                    _record(ctx, job_id, round_id, frame, fallback, i, payload, summary, mask_source="chroma_key")
        fit_job_ids = _fit_jobs_of(ctx, job_id)
        result = {"job_id": job_id, **summary, "fit_job_ids": fit_job_ids}
        with ctx.session_factory.begin() as session:
            jobs.finish(session, job_id, JobState.succeeded, result=result)
        if round_job_id is not None:
            touch_round(ctx, int(round_job_id))
        return result
    except JobCancelledError:
        return {"job_id": job_id, "cancelled": True, "fit_job_ids": []}
    except (InputError, DomainError, ValueError, SoftTimeLimitExceeded) as exc:
        message = getattr(exc, "message", None) or str(exc) or exc.__class__.__name__
        log.warning("prediction job %s failed: %s", job_id, message)
        with ctx.session_factory.begin() as session:
            jobs.finish(session, job_id, JobState.failed, error=message[:2000])
        # What was recorded stays: its fits still run.
        return {"job_id": job_id, "failed": message, "fit_job_ids": _fit_jobs_of(ctx, job_id)}


def _predict(ctx: WorkerContext, mvnet: Any, handsegnet: Any, frames: list[Any], wrig: WorkingRig) -> Any:
    """predict_frames on the working copies; a detector-backed MVNet (its checkpoint says so) also gets the
    detector's keypoints. The masks come back at the views' full size."""
    # deferred: as in load_net (torch, and the detector's runtime, only where a job predicts)
    from workers.detector import DetectorUnavailableError
    from workers.nets.predict import predict_frames

    try:
        out = predict_frames(mvnet, [f.frame for f in frames], list(wrig.cameras), handsegnet,
                             handedness=ROUND_HANDEDNESS, detection_cache=detection_cache(ctx))
    except DetectorUnavailableError as exc:
        raise InputError(f"this MVNet is detector-backed, but {exc}; install the detector or train a paper-only "
                         "one (HANDLOOP_MVNET_DETECTOR=false)") from None
    return dataclasses.replace(out, masks=[probabilities_at_full_resolution(m, wrig) for m in out.masks])


def _record(ctx: WorkerContext, job_id: int, round_id: int | None, frame: Any, out: Any, i: int,
            payload: dict[str, Any], summary: dict[str, int], mask_source: str) -> None:
    keypoints = out.keypoints.keypoints_3d[i]
    confidence = out.keypoints.confidence[i]
    if not np.isfinite(keypoints).all():
        summary["not_localised"] += 1
        return
    from_handsegnet = mask_source == "handsegnet"
    threshold = 0.5  # HandSegNetConfig.threshold of every configuration
    masks = {view_id: np.asarray(prob) > threshold for view_id, prob in zip(frame.view_ids, out.masks[i], strict=True)}
    try:
        with ctx.session_factory.begin() as session:
            prediction = records.record_prediction(
                session, ctx.storage, frame.sample_id, keypoints_m=keypoints.tolist(),
                confidences=np.clip(confidence, 0, 1).tolist(), mvnet_version=payload["mvnet_version"],
                handsegnet_version=payload.get("handsegnet_version") if from_handsegnet else None,
                masks=masks if from_handsegnet else None, round_id=round_id, job_id=job_id)
            session.flush()
            state = session.get(Sample, frame.sample_id).state
            if state in REFITTABLE:
                records.queue_fit(session, ctx.job_queue, frame.sample_id, source="prediction", round_id=round_id,
                                  payload={"prediction_id": prediction.id, "predict_job_id": job_id,
                                           "mask_source": mask_source}, enqueue=False)
        summary["predicted"] += 1
        summary[f"masks_{mask_source}"] = summary.get(f"masks_{mask_source}", 0) + 1
    except DomainError as exc:
        log.info("prediction of sample %s not recorded: %s", frame.sample_id, exc.message)


def _fit_jobs_of(ctx: WorkerContext, predict_job_id: int) -> list[int]:
    """Unfinished fit jobs made from this predict job's predictions."""
    with ctx.session_factory() as session:
        predictions = set(session.execute(select(Prediction.id).where(Prediction.job_id == predict_job_id)).scalars())
        if not predictions:
            return []
        rows = session.execute(select(Job.id, Job.payload).where(
            Job.kind == "fit", Job.state.in_([JobState.queued, JobState.running]),
            Job.sample_id.in_(select(Prediction.sample_id).where(Prediction.job_id == predict_job_id)))).all()
    return sorted(job_id for job_id, p in rows if (p or {}).get("prediction_id") in predictions)


def touch_round(ctx: WorkerContext, round_job_id: int) -> None:
    """The round's progress after one of its predict or fit jobs ended (workers.tasks.round_progress)."""
    with ctx.session_factory.begin() as session:
        round_progress.refresh(session, round_job_id, ctx.settings)
