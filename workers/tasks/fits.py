"""Fit jobs: load each sample's inputs, fit the hand model (batched per rig and configuration), record.

Fits from annotations use the paper's first-round weights with the clicks and the corrected (else the
chroma-key) masks; fits from predictions use MVNet's 3D keypoints (weighted by confidence) and HandSegNet's
masks with the later-round weights (`LossWeights.later_rounds()`); round 0's fits from the pretrained detector's
keypoints are led by the masks where they have them (`LossWeights.detector_with_silhouettes()`). One sample that
cannot be fitted is recorded as a failure (back to the annotators) and never sinks its batch. Every job is claimed
first and recorded in its own transaction, so a redelivered task neither fits twice nor records twice.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy import select
from sqlalchemy.exc import DataError, IntegrityError

from backend.models.capture import Sample
from backend.models.enums import JobState, SampleState
from backend.models.jobs import Job
from backend.services.captures.masks import encode_png
from backend.services.errors import DomainError
from backend.services.jobs import jobs
from backend.services.jobs.jobs import JobStillRunningError
from backend.services.review import precision_target
from backend.services.review.verification import HeuristicThresholds
from backend.settings import Settings
from workers.capture.schema import CaptureError
from workers.fitting.config import FitConfig, source_weights
from workers.fitting.inputs import FitInputError
from workers.tasks import cross_checks, records
from workers.tasks.context import WorkerContext
from workers.tasks.detection_inputs import SOURCE as DETECTOR_SOURCE
from workers.tasks.fit_sources import fit_input
from workers.tasks.inference import touch_round
from workers.tasks.inputs import FitInput, InputError, load_frames
from workers.tasks.json_values import json_safe
from workers.tasks.progress import JobCancelledError, ProgressReporter

log = logging.getLogger(__name__)

# What makes one sample's fit impossible (as opposed to a bug or an outage, which fail the task).
SAMPLE_ERRORS = (InputError, FitInputError, CaptureError, DomainError, ValueError)


@dataclass
class FitSummary:
    """What a batch did: fits recorded, samples failed (with reasons), jobs skipped (final) or left to a
    later delivery (running under another attempt that may be alive)."""

    fitted: list[int] = field(default_factory=list)  # fit ids
    failed: dict[int, str] = field(default_factory=dict)  # job id -> error
    skipped: list[int] = field(default_factory=list)  # job ids
    running_elsewhere: list[JobStillRunningError] = field(default_factory=list)  # one per job
    seconds: float = 0.0  # the whole batch
    fit_seconds: float = 0.0  # inside FittingEngine.fit

    def raise_for_running_elsewhere(self) -> None:
        """After the others are done: the delivery must come back for jobs that may run elsewhere."""
        if self.running_elsewhere:
            raise JobStillRunningError.merge(self.running_elsewhere)

    def to_dict(self) -> dict[str, Any]:
        return {"fitted": len(self.fitted), "fit_ids": self.fitted, "failed": len(self.failed),
                "errors": {str(k): v for k, v in self.failed.items()}, "skipped": len(self.skipped),
                "running_elsewhere": [i for e in self.running_elsewhere for i in e.job_ids],
                "seconds": round(self.seconds, 3), "fit_seconds": round(self.fit_seconds, 3)}


def fit_config_from_settings(settings: Settings, source: str, with_masks: bool = False) -> FitConfig:
    """The fit's settings for a source ("annotation", "prediction", "detector"; `source_weights`) and the settings'
    solver schedule; `with_masks`: the frames have masks. Also what `handloop bench detect` fits with."""
    return FitConfig(weights=source_weights(source, with_masks), optimizer=settings.fit_optimizer,
                     global_iterations=settings.fit_global_iterations, full_iterations=settings.fit_full_iterations)


def fit_config(ctx: WorkerContext, source: str, with_masks: bool = False) -> FitConfig:
    """`fit_config_from_settings` with the worker's settings."""
    return fit_config_from_settings(ctx.settings, source, with_masks)


def has_masks(fi: FitInput) -> bool:
    """Whether any view of the fit input has a mask."""
    masks = fi.observations.masks
    return masks is not None and any(m is not None for m in masks)


def engine_for(ctx: WorkerContext, fi: FitInput, config: FitConfig) -> Any:
    """A FittingEngine for this rig, configuration and hand side, built once per process."""
    from workers.fitting.engine import FittingEngine  # deferred: torch with the first fit

    return ctx.cached(("engine", fi.rig.digest, config, fi.side),
                      lambda: FittingEngine(ctx.hand_model(fi.side), list(fi.rig.cameras), config))


def run_fit_jobs(ctx: WorkerContext, job_ids: list[int], *, parent: tuple[int, float, float] | None = None,
                 heartbeat_of: int | None = None) -> FitSummary:
    """Claim, fit and record these fit jobs (any mix of sources and rigs); `heartbeat_of`: a round job kept
    alive while they run."""
    started = time.perf_counter()
    summary = FitSummary()
    claimed = _claim_and_load_all(ctx, job_ids, summary)
    groups: dict[tuple[str, str, bool, str], list[FitInput]] = defaultdict(list)
    for fi in claimed:
        # Only a detector's fits weigh differently with masks: other sources keep one batch per rig and side.
        groups[(fi.rig.digest, fi.source, fi.source == DETECTOR_SOURCE and has_masks(fi), fi.side)].append(fi)
    progress = ProgressReporter(ctx, [fi.job_id for fi in claimed], parent=parent, heartbeat_of=heartbeat_of)
    done = 0
    try:
        for (_, source, with_masks, _side), group in groups.items():
            config = fit_config(ctx, source, with_masks)
            engine = engine_for(ctx, group[0], config)

            def tick(fraction: float, message: str, offset: int = done, size: int = len(group)) -> None:
                progress((offset + fraction * size) / max(1, len(claimed)), f"fitting: {message}")

            _fit_group(ctx, engine, group, tick, summary)
            done += len(group)
    except (SoftTimeLimitExceeded, JobCancelledError) as exc:
        reason = "time limit exceeded" if isinstance(exc, SoftTimeLimitExceeded) else "cancelled"
        with ctx.session_factory.begin() as session:
            for fi in claimed:
                if fi.job_id not in summary.failed and not jobs.is_final(session, fi.job_id):
                    _record_failure_in(session, fi.sample_id, fi.job_id, f"fit stopped: {reason}", summary)
        if isinstance(exc, SoftTimeLimitExceeded):
            log.warning("fit batch %s stopped at its time limit", job_ids)
    summary.seconds = time.perf_counter() - started
    return summary


def run_fit_jobs_batched(ctx: WorkerContext, job_ids: list[int], *, round_job_id: int | None = None
                         ) -> dict[str, Any]:
    """`run_fit_jobs` over chunks of `fit_batch_size`; in a round, its progress is updated after each chunk."""
    size = ctx.settings.fit_batch_size
    total = FitSummary()
    for start in range(0, len(job_ids), size):
        part = run_fit_jobs(ctx, job_ids[start:start + size], heartbeat_of=round_job_id)
        total.fitted += part.fitted
        total.failed.update(part.failed)
        total.skipped += part.skipped
        total.seconds += part.seconds
        total.fit_seconds += part.fit_seconds
        total.running_elsewhere += part.running_elsewhere
        if round_job_id is not None:
            touch_round(ctx, int(round_job_id))
    total.raise_for_running_elsewhere()
    return total.to_dict()


def _claim_and_load_all(ctx: WorkerContext, job_ids: list[int], summary: FitSummary) -> list[FitInput]:
    """Claim the jobs and load their inputs in one transaction (one commit per batch: on SQLite each commit
    is a disk sync), each job in a savepoint of its own, so that one bad job changes nothing for the others."""
    claimed: list[FitInput] = []
    failures: list[tuple[int, int, str]] = []
    with ctx.session_factory.begin() as session:
        sample_ids = [s for s in session.execute(select(Job.sample_id).where(Job.id.in_(job_ids))).scalars() if s]
        try:
            frames = load_frames(ctx, session, sample_ids)
        except SAMPLE_ERRORS:
            frames = {}  # one bad sample: each is loaded (and fails) on its own below
        for job_id in job_ids:
            sample_id = None
            try:
                with session.begin_nested():
                    job = ctx.claim(session, job_id)
                    if job is None:
                        summary.skipped.append(job_id)
                        continue
                    sample_id = job.sample_id
                    problem = _not_fittable(session, job)
                    if problem:
                        jobs.finish(session, job_id, JobState.failed, error=problem)
                        summary.failed[job_id] = problem
                        continue
                    claimed.append(fit_input(ctx, session, job, frames))
            except JobStillRunningError as exc:  # the savepoint is rolled back: the job is as it was
                summary.running_elsewhere.append(exc)
            except SAMPLE_ERRORS as exc:  # the savepoint is rolled back: the job is as it was
                message = getattr(exc, "message", None) or str(exc)
                log.warning("fit job %s: cannot load inputs: %s", job_id, message)
                if sample_id is not None:
                    failures.append((sample_id, job_id, f"inputs: {message}"))
        for sample_id, job_id, error in failures:
            _record_failure_in(session, sample_id, job_id, error, summary)
    return claimed


def _not_fittable(session: Any, job: Any) -> str | None:
    if job.kind != "fit":
        return f"job {job.id} is a {job.kind} job, not a fit"
    state = session.get(Sample, job.sample_id).state if job.sample_id is not None else None
    if state != SampleState.fitting:
        return f"sample {job.sample_id} is '{state}', not 'fitting'; nothing to fit"
    return None


def _fit_group(ctx: WorkerContext, engine: Any, group: list[FitInput], tick: Any, summary: FitSummary) -> None:
    valid: list[FitInput] = []
    for fi in group:
        try:
            fi.observations.validate(engine.cameras)
            valid.append(fi)
        except FitInputError as exc:
            _record_failure(ctx, fi.sample_id, fi.job_id, f"inputs: {exc}", summary)
    if not valid:
        return
    try:
        started = time.perf_counter()
        if valid[0].source == DETECTOR_SOURCE:  # groups hold one source
            results, valid = _fit_detector_twice(engine, valid, tick)
        else:
            results = engine.fit([fi.observations for fi in valid], progress=tick)
        summary.fit_seconds += time.perf_counter() - started
    except (SoftTimeLimitExceeded, JobCancelledError):
        raise
    except Exception as exc:  # one bad frame must not sink the others: fit them one by one
        if len(valid) == 1:
            _record_failure(ctx, valid[0].sample_id, valid[0].job_id, f"fit failed: {exc}", summary)
            return
        log.warning("batch fit of %d samples failed (%s); fitting them one by one", len(valid), exc)
        for fi in valid:
            _fit_group(ctx, engine, [fi], tick, summary)
        return
    _record_all(ctx, list(zip(valid, results, strict=True)), engine.config, summary)


def _fit_detector_twice(engine: Any, group: list[FitInput], tick: Any) -> tuple[list[Any], list[FitInput]]:
    """Fits from a detector's keypoints (`workers.fitting.reweight.fit_reweighted`: a first fit, then the first
    continued with each keypoint reweighted by its residual to it). Returns the second fits and the inputs marked
    `residual_reweighted`."""
    from workers.fitting.reweight import fit_reweighted  # deferred: torch with the first fit

    results = fit_reweighted(engine, [fi.observations for fi in group], progress=tick)
    marked = [dataclasses.replace(fi, inputs={**fi.inputs, "residual_reweighted": True}) for fi in group]
    return results, marked


def _record_all(ctx: WorkerContext, fitted: list[tuple[FitInput, Any]], config: FitConfig, summary: FitSummary
                ) -> None:
    """Store the model masks, then record every fit in one transaction, each in its own savepoint."""
    rows = []
    for fi, result in fitted:
        # Model masks are the HandSegNet labels of later rounds and the reviewers' overlay: stored as files.
        mask_keys = {}
        for view_id, mask in zip(fi.view_ids, result.model_masks, strict=True):
            key = f"fits/sample-{fi.sample_id}/job-{fi.job_id}/view-{view_id}.png"
            ctx.storage.put_bytes(key, _png(mask))
            mask_keys[str(view_id)] = key
        ious = {view_id: float(min(1.0, max(0.0, iou)))
                for view_id, iou in zip(fi.view_ids, result.diagnostics.iou_per_view, strict=True) if np.isfinite(iou)}
        diagnostics = json_safe({
            **result.diagnostics.to_dict(), "model_mask_keys": mask_keys, "hand_model": result.hand_model,
            "hand_side": fi.side,
            "weights": {"kp2d": config.weights.kp2d, "kp3d": config.weights.kp3d, "seg": config.weights.seg},
            "iterations_schedule": [config.global_iterations, config.full_iterations]})
        rows.append((fi, result, ious, diagnostics))
    unstorable: list[tuple[FitInput, str]] = []
    with ctx.session_factory.begin() as session:
        thresholds = precision_target.thresholds_in_force(session, ctx.settings)  # the round's (issue 40)
        detector_thresholds = (HeuristicThresholds.from_settings(ctx.settings, "detector_heuristic_")
                               if ctx.settings.detector_heuristic else None)
        cross_thresholds, earlier_fit_thresholds = cross_checks.thresholds_from_settings(ctx.settings)
        for fi, result, ious, diagnostics in rows:
            try:
                with session.begin_nested():
                    fit = records.record_fit(
                        session, fi.sample_id, params=result.theta.tolist(), keypoints_m=result.keypoints.tolist(),
                        view_ious=ious, diagnostics=diagnostics, inputs=json_safe(fi.inputs),
                        model_file=result.hand_model, thresholds=thresholds, job_id=fi.job_id,
                        prediction_id=fi.prediction_id, vertices_m=result.vertices,
                        detector_thresholds=detector_thresholds, cross_thresholds=cross_thresholds,
                        earlier_fit_thresholds=earlier_fit_thresholds,
                        review_pre_annotation_fit=ctx.settings.review_pre_annotation_fit)
                    session.flush()
                summary.fitted.append(fit.id)
            except (DomainError, IntegrityError) as exc:  # cancelled, or recorded by a concurrent duplicate
                log.info("fit of job %s not recorded: %s", fi.job_id, getattr(exc, "message", exc))
                summary.skipped.append(fi.job_id)
            except DataError as exc:  # the database refused a value: this fit can never be stored, so say so
                log.error("fit of job %s could not be stored: %s", fi.job_id, exc)
                unstorable.append((fi, f"fit could not be stored: {exc.orig}"))
        for fi, error in unstorable:
            _record_failure_in(session, fi.sample_id, fi.job_id, error, summary)


def _png(mask: np.ndarray) -> bytes:
    """An 8-bit grayscale PNG (0 / 255) of a bool mask; OpenCV's encoder at low compression, a few times
    faster than the API's pure-numpy encoder on the fit's hot path."""
    ok, data = cv2.imencode(".png", np.asarray(mask, np.uint8) * 255, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        return encode_png(mask)
    return data.tobytes()


def _record_failure(ctx: WorkerContext, sample_id: int, job_id: int, error: str, summary: FitSummary) -> None:
    with ctx.session_factory.begin() as session:
        _record_failure_in(session, sample_id, job_id, error, summary)


def _record_failure_in(session: Any, sample_id: int, job_id: int, error: str, summary: FitSummary) -> None:
    summary.failed[job_id] = error
    try:
        with session.begin_nested():
            records.record_fit_failure(session, sample_id, job_id, error[:2000])
    except DomainError as exc:
        log.warning("failure of fit job %s not recorded: %s", job_id, exc.message)
