"""The bootstrap round (paper: "Iterative Refinement"), as database steps that a Celery canvas strings together:

    handloop.round            start: claim the round job, create its train jobs
      chord(train_handsegnet, train_mvnet)                        gpu queue, checkpoints round-NNN/
      -> handloop.round_inference: one predict job per batch of samples not yet in D
           chord(chain(predict_batch, fit_batch) per batch)        gpu, then cpu
           -> handloop.heuristic -> handloop.build_review_queue -> handloop.round_finish

Backend round index r (r >= 1) collects the streams that networks trained on rounds 0 ... r-1 produce:
D_{i+1} = D_i + D^h_i + D^m_i + D^l_i, where D^h joins as fits pass the heuristic, D^m and D^l as reviewers
verify the queue built here. Every step re-reads the database and is safe to run again: if the round's
canvas is lost (a worker died and the broker did not deliver its tasks again), the outbox re-sends the
round job once its heartbeat is stale and `start_round` continues from what is done. The round job's progress
follows these phases (workers.tasks.round_progress).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.models.capture import Sample, Sequence
from backend.models.enums import JobKind, JobState, RoundState, SampleState, Stream
from backend.models.fits import Fit, Prediction
from backend.models.jobs import Job
from backend.models.review import Round, RoundMember
from backend.services.jobs import jobs
from backend.services.review import precision_target, review
from backend.services.review.verification import ReviewPolicy, heuristic_verdict
from workers.tasks import round_progress
from workers.tasks.context import WorkerContext
from workers.tasks.inference import PREDICTABLE
from workers.tasks.records import CROSS, EARLIER_FIT, iou_reference
from workers.tasks.training import NETS, checkpoint_of, version_of

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InferencePlan:
    predict_job_ids: list[int] = field(default_factory=list)
    fit_batches: list[list[int]] = field(default_factory=list)


def _jobs_of(session: Session, round_id: int, kind: JobKind) -> list[Job]:
    return list(session.execute(select(Job).where(Job.round_id == round_id, Job.kind == kind).order_by(Job.id))
                .scalars())


def _merge_result(job: Job, **values: Any) -> None:
    job.result = {**(job.result or {}), **values}  # a new dict: JSON columns track assignment, not mutation


def _fail(session: Session, round_job: Job, message: str) -> None:
    log.warning("round job %s failed: %s", round_job.id, message)
    jobs.finish(session, round_job.id, JobState.failed, error=message[:2000])


def start_round(ctx: WorkerContext, round_job_id: int) -> list[int] | None:
    """Claim the round job; the train jobs still to run (created on first call). None: nothing to do."""
    with ctx.session_factory.begin() as session:
        job = ctx.claim(session, round_job_id)
        if job is None:
            return None
        round_ = session.get(Round, job.round_id) if job.round_id is not None else None
        if round_ is None or round_.state != RoundState.running:
            _fail(session, job, f"round job {round_job_id}: its round is {getattr(round_, 'state', 'missing')}")
            return None
        existing = {(j.payload or {}).get("net"): j for j in _jobs_of(session, round_.id, JobKind.train)}
        to_run = []
        for net in NETS:
            given = getattr(round_, f"{net}_version")
            if given and given != version_of(round_.index, net):
                try:
                    if not checkpoint_of(ctx, given).is_file():
                        raise ValueError(f"no checkpoint at {checkpoint_of(ctx, given)}")
                except ValueError as exc:
                    _fail(session, job, f"round {round_.index} was launched with {net} version {given!r}: {exc}")
                    return None
                continue  # launched with an existing model: no training
            previous = existing.get(net)
            if previous is not None and previous.state == JobState.succeeded:
                continue
            if previous is not None and previous.state in (JobState.failed, JobState.cancelled):
                _fail(session, job, f"training {net} {previous.state}: {previous.error or ''}")
                return None
            if previous is None:
                previous = jobs.create(session, ctx.job_queue, JobKind.train, round_id=round_.id, enqueue=False,
                                       payload={"net": net, "round_job_id": round_job_id})
            to_run.append(previous.id)
        # The samples it will predict, as the progress bar's estimate until the predict jobs exist.
        estimate = session.execute(select(func.count()).select_from(Sample)
                                   .where(Sample.state.in_(PREDICTABLE))).scalar_one()
        _merge_result(job, round_index=round_.index, candidates_estimate=int(estimate),
                      train_on_rounds_up_to=(job.payload or {}).get("train_on_rounds_up_to"))
        session.flush()
        round_progress.refresh(session, round_job_id, ctx.settings)
        return to_run


def _round_project(session: Session, up_to_index: int) -> int | None:
    """The project (rig) whose accepted samples the round trained on: the one with the most."""
    row = session.execute(
        select(Sequence.project_id, func.count()).select_from(RoundMember)
        .join(Round, Round.id == RoundMember.round_id).join(Sample, Sample.id == RoundMember.sample_id)
        .join(Sequence, Sequence.id == Sample.sequence_id).where(Round.index <= up_to_index)
        .group_by(Sequence.project_id).order_by(func.count().desc(), Sequence.project_id).limit(1)
    ).first()
    return None if row is None else int(row[0])


def plan_inference(ctx: WorkerContext, round_job_id: int) -> InferencePlan | None:
    """After training: predict jobs for the samples not yet in the dataset (created on first call), and fit
    batches left over from earlier attempts. None: the round job is over (failed, cancelled)."""
    with ctx.session_factory.begin() as session:
        job = session.get(Job, round_job_id)
        if job is None or JobState(job.state) in jobs.FINAL_STATES:
            return None
        round_ = session.get(Round, job.round_id)
        if round_ is None or round_.state != RoundState.running:
            _fail(session, job, "the round is no longer running")
            return None
        for train in _jobs_of(session, round_.id, JobKind.train):
            if train.state != JobState.succeeded:
                net = (train.payload or {}).get("net")
                _fail(session, job, f"training {net} is {train.state}: {train.error or ''}")
                return None
        versions = {net: getattr(round_, f"{net}_version") for net in NETS}
        if not versions["mvnet"]:
            _fail(session, job, "no MVNet version for this round")
            return None
        up_to = int((job.payload or {}).get("train_on_rounds_up_to", round_.index - 1))
        project_id = _round_project(session, up_to)
        predict_jobs = _jobs_of(session, round_.id, JobKind.predict)
        if not predict_jobs and project_id is not None:
            candidates = list(session.execute(
                select(Sample.id).join(Sequence, Sequence.id == Sample.sequence_id)
                .where(Sequence.project_id == project_id, Sample.state.in_(PREDICTABLE)).order_by(Sample.id)
            ).scalars())
            size = ctx.settings.predict_batch_size
            for start in range(0, len(candidates), size):
                predict_jobs.append(jobs.create(
                    session, ctx.job_queue, JobKind.predict, round_id=round_.id, enqueue=False,
                    payload={"sample_ids": candidates[start:start + size], "round_job_id": round_job_id,
                             "mvnet_version": versions["mvnet"], "handsegnet_version": versions["handsegnet"]}))
            _merge_result(job, candidates=len(candidates), project_id=project_id)
        session.flush()
        pending = [p.id for p in predict_jobs if JobState(p.state) not in jobs.FINAL_STATES]
        done = {p.id for p in predict_jobs} - set(pending)
        leftover = [j.id for j in _jobs_of(session, round_.id, JobKind.fit)
                    if JobState(j.state) not in jobs.FINAL_STATES and (j.payload or {}).get("predict_job_id") in done]
        size = ctx.settings.fit_batch_size
        batches = [leftover[i:i + size] for i in range(0, len(leftover), size)]
        _merge_result(job, mvnet_version=versions["mvnet"], handsegnet_version=versions["handsegnet"])
        round_progress.refresh(session, round_job_id, ctx.settings)
        return InferencePlan(pending, batches)


class _HeuristicCounts:
    """Fits, those evaluated (a fit without view IoUs is not), accepted (of them by a cross-estimator check: `cross`,
    MVNet's fit against the detector's lift; `earlier_fit`, the pre-annotation's fit against MVNet's prediction), and
    failures by criterion of the paper's heuristic."""

    def __init__(self) -> None:
        self.fits = self.evaluated = self.accepted = self.cross = self.earlier_fit = 0
        self.reasons: dict[str, int] = {}

    def add(self, record: dict[str, Any] | None) -> None:
        self.fits += 1
        if record is None:
            return
        self.evaluated += 1
        self.accepted += bool(record.get("accepted"))
        self.cross += bool(record.get("accepted")) and record.get("estimator") == CROSS
        self.earlier_fit += bool(record.get("accepted")) and record.get("estimator") == EARLIER_FIT
        for reason in record.get("failed", []):
            key = _criterion(reason)
            self.reasons[key] = self.reasons.get(key, 0) + 1

    def summary(self) -> dict[str, Any]:
        return {"fits": self.fits, "evaluated": self.evaluated, "accepted": self.accepted, "cross": self.cross,
                "earlier_fit": self.earlier_fit,
                "failures": dict(sorted(self.reasons.items(), key=lambda kv: -kv[1])[:8])}


def run_heuristic(ctx: WorkerContext, round_job_id: int) -> dict[str, Any] | None:
    """The paper's heuristic over the round's fits from predictions: applies it to any fit not evaluated yet
    (record_fit evaluates each new one) and summarises: fits, evaluated, accepted (D^h), most common failures;
    the same per sequence kind in "by_kind" ("green_screen": chroma-keyed sequences, "cluttered": the others)."""
    with ctx.session_factory.begin() as session:
        thresholds = precision_target.thresholds_in_force(session, ctx.settings)  # the round's (issue 40)
        job = session.get(Job, round_job_id)
        if job is None or JobState(job.state) in jobs.FINAL_STATES:
            return None
        rows = session.execute(select(Fit, Sample.green_screen).join(Sample, Sample.id == Fit.sample_id)
                               .where(Fit.round_id == job.round_id, Fit.prediction_id.is_not(None))
                               .order_by(Fit.id)).all()
        total = _HeuristicCounts()
        by_kind = {kind: _HeuristicCounts() for kind in ("green_screen", "cluttered")}
        for fit, green_screen in rows:
            if fit.heuristic is None and fit.view_ious:
                prediction = session.get(Prediction, fit.prediction_id)
                verdict = heuristic_verdict(prediction.confidences, fit.view_ious.values(), prediction.keypoints_m,
                                            fit.keypoints_m, thresholds)
                # Evaluated late (no acceptance here: only record_fit routes samples, in its transaction).
                fit.heuristic = {"accepted": False, "late": True, "would_accept": verdict.accepted,
                                 "failed": list(verdict.failed), **verdict.metrics,
                                 "iou_reference": iou_reference(fit.inputs or {})}
            total.add(fit.heuristic)
            by_kind["green_screen" if green_screen else "cluttered"].add(fit.heuristic)
        summary = {**total.summary(), "by_kind": {kind: c.summary() for kind, c in by_kind.items()}}
        _merge_result(job, heuristic=summary)
        round_progress.refresh(session, round_job_id, ctx.settings)
        return summary


def _criterion(reason: str) -> str:
    """The heuristic criterion a failure message (services.review.verification.heuristic_verdict) is about."""
    for name in ("mean confidence", "min keypoint confidence", "mean IoU", "mean 3D distance", "max 3D distance"):
        if reason.startswith(name):
            return name
    return "low-IoU views" if "views have IoU" in reason else reason[:40]


def build_review_queue(ctx: WorkerContext, round_job_id: int) -> dict[str, Any] | None:
    """The manual verification queue by the paper's policy (services.review.review.build_queue)."""
    with ctx.session_factory.begin() as session:
        job = session.get(Job, round_job_id)
        if job is None or JobState(job.state) in jobs.FINAL_STATES:
            return None
        picked = review.build_queue(session, ReviewPolicy.from_settings(ctx.settings), None)
        summary = {"queued": len(picked)}
        _merge_result(job, review_queue=summary)
        round_progress.refresh(session, round_job_id, ctx.settings)
        return summary


def finish_round(ctx: WorkerContext, round_job_id: int) -> dict[str, Any] | None:
    """Record what the round did and finish its job: sizes, counts per stream, model versions."""
    with ctx.session_factory.begin() as session:
        job = session.get(Job, round_job_id)
        if job is None or JobState(job.state) in jobs.FINAL_STATES:
            return None
        round_ = session.get(Round, job.round_id)
        streams = dict(session.execute(
            select(RoundMember.stream, func.count()).where(RoundMember.round_id == round_.id)
            .group_by(RoundMember.stream)).all())
        before = session.execute(
            select(func.count()).select_from(RoundMember).join(Round, Round.id == RoundMember.round_id)
            .where(Round.index < round_.index)).scalar_one()
        fit_states = dict(session.execute(select(Job.state, func.count()).where(Job.round_id == round_.id,
                                                                                 Job.kind == JobKind.fit)
                                          .group_by(Job.state)).all())
        predictions = session.execute(select(func.count()).select_from(Prediction)
                                      .where(Prediction.round_id == round_.id)).scalar_one()
        counts = {s.value: int(streams.get(s.value, 0)) for s in Stream}
        result = {
            "round_index": round_.index,
            "dataset_before": int(before),  # |D_i|, what the networks were trained on (all rigs)
            "added": counts,  # so far: D^h now, D^m and D^l as reviewers verify
            "dataset_after": int(before) + sum(counts.values()),
            "predictions": int(predictions),
            "fits": {str(k): int(v) for k, v in fit_states.items()},
            "samples_by_state": {str(k): int(v) for k, v in session.execute(
                select(Sample.state, func.count()).group_by(Sample.state)).all()},
            "mvnet_version": round_.mvnet_version, "handsegnet_version": round_.handsegnet_version,
        }
        round_.counts = counts
        _merge_result(job, **result)
        final = dict(job.result)
        jobs.finish(session, round_job_id, JobState.succeeded, result=final)
        in_review = session.execute(select(func.count()).select_from(Sample)
                                    .where(Sample.state == SampleState.in_review)).scalar_one()
        log.info("round %s done: %s; %d samples in review", round_.index, result, in_review)
        return final
