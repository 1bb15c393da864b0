"""Recording machine output: MVNet/HandSegNet predictions and hand-model fits.

Called by the workers (the worker issue wraps each in a Celery task that calls one of these); a new fit
runs the heuristic when the sample has a prediction (or, for a pre-annotation's fit, the detector's heuristic), and
routes the sample on from there.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.models.capture import Sample
from backend.models.enums import DecisionKind, JobKind, JobState, MaskKind, SampleState, Stream
from backend.models.fits import Fit, Prediction
from backend.models.labels import Mask
from backend.models.review import Decision
from backend.services import audit
from backend.services.captures.masks import encode_png
from backend.services.captures.samples import views_of
from backend.services.captures.state_machine import transition
from backend.services.captures.storage import Storage
from backend.services.errors import ConflictError, InvalidInputError
from backend.services.jobs import fit_samples, jobs
from backend.services.leases import queues
from backend.services.review import agreement, label_audits
from backend.services.review.verification import HeuristicResult, HeuristicThresholds, heuristic_verdict
from backend.services.rounds import rounds
from workers.handmodel.params import NUM_PARAMS, HandParams
from workers.tasks import cross_checks
from workers.tasks.cross_checks import DETECTOR_SOURCE

log = logging.getLogger(__name__)

# Which estimates a heuristic verdict compared (fit.heuristic["estimator"]): MVNet's fit and prediction (the paper's),
# a pre-annotation's fit and the detector's lift, MVNet's fit and the lift (CROSS), the pre-annotation's fit and
# MVNet's prediction (EARLIER_FIT: the sample is accepted with the pre-annotation's fit); workers.tasks.cross_checks.
MVNET, CROSS, EARLIER_FIT = "mvnet", "mvnet+detector", "detector+mvnet"
ESTIMATOR_NAMES = {MVNET: "MVNet", DETECTOR_SOURCE: "detector", CROSS: "MVNet's fit against the detector's lift",
                   EARLIER_FIT: "the pre-annotation's fit against MVNet's prediction"}

NUM_KEYPOINTS = 21


def _finite_array(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise InvalidInputError(f"{name} must have shape {shape}, got {array.shape}")
    if not np.isfinite(array).all():
        raise InvalidInputError(f"{name} contains non-finite numbers")
    return array


def add_mask(session: Session, storage: Storage, view_id: int, kind: MaskKind, mask: np.ndarray, key: str, *,
             actor_id: int | None = None, model_version: str | None = None) -> Mask:
    version = session.execute(select(func.max(Mask.version)).where(Mask.view_id == view_id)).scalar_one() or 0
    storage.put_bytes(key, encode_png(mask))
    row = Mask(view_id=view_id, kind=kind, version=version + 1, storage_key=key, created_by_id=actor_id,
               model_version=model_version)
    session.add(row)
    return row


def record_prediction(session: Session, storage: Storage, sample_id: int, *, keypoints_m: Sequence[Sequence[float]],
                      confidences: Sequence[float], mvnet_version: str, handsegnet_version: str | None = None,
                      masks: Mapping[int, np.ndarray] | None = None, round_id: int | None = None,
                      job_id: int | None = None) -> Prediction:
    """MVNet keypoints (21, 3) metres with confidences (21,), and HandSegNet masks per view id."""
    kp = _finite_array(keypoints_m, (NUM_KEYPOINTS, 3), "keypoints_m")
    conf = _finite_array(confidences, (NUM_KEYPOINTS,), "confidences")
    if ((conf < 0) | (conf > 1)).any():
        raise InvalidInputError("confidences must lie in [0, 1]")
    sample = queues.load_locked(session, sample_id)
    views = {v.id: v for v in views_of(session, sample_id, with_masks=False)}
    prediction = Prediction(sample_id=sample_id, round_id=round_id, job_id=job_id, mvnet_version=mvnet_version,
                            handsegnet_version=handsegnet_version, keypoints_m=kp.tolist(),
                            confidences=conf.tolist(), mean_confidence=float(conf.mean()))
    session.add(prediction)
    session.flush()
    for view_id, mask in (masks or {}).items():
        view = views.get(view_id)
        if view is None:
            raise InvalidInputError(f"view {view_id} is not a view of sample {sample_id}")
        if np.shape(mask) != (view.height, view.width):
            raise InvalidInputError(f"mask for view {view_id} has shape {np.shape(mask)}; expected "
                               f"{(view.height, view.width)}")
        add_mask(session, storage, view_id, MaskKind.predicted, np.asarray(mask, bool),
                 f"masks/predicted/{view_id}/{prediction.id}.png", model_version=handsegnet_version)
    sample.confidence = prediction.mean_confidence
    audit.record(session, None, "prediction.create", "sample", sample_id, prediction_id=prediction.id,
                 mvnet_version=mvnet_version)
    return prediction


def queue_fit(session: Session, queue: jobs.JobQueue, sample_id: int, *, source: str,
              actor_id: int | None = None, round_id: int | None = None, payload: dict[str, Any] | None = None,
              enqueue: bool = True):
    """Move a sample to 'fitting' and queue a fit job (e.g. from fresh predictions in round i).
    `enqueue=False`: the caller runs the job (a round's fit batches), see services.jobs.jobs.create."""
    sample = queues.load_locked(session, sample_id)
    transition(session, sample, SampleState.fitting, actor_id, reason=f"fit queued ({source})")
    return jobs.create(session, queue, JobKind.fit, actor_id=actor_id, sample_id=sample_id, round_id=round_id,
                       payload={"source": source, **(payload or {})}, enqueue=enqueue)


def record_fit(session: Session, sample_id: int, *, params: Sequence[float], keypoints_m: Sequence[Sequence[float]],
               view_ious: Mapping[int, float], diagnostics: dict[str, Any], inputs: dict[str, Any],
               model_file: str, thresholds: HeuristicThresholds, job_id: int | None = None,
               prediction_id: int | None = None, vertices_m: np.ndarray | None = None,
               detector_thresholds: HeuristicThresholds | None = None,
               cross_thresholds: HeuristicThresholds | None = None,
               earlier_fit_thresholds: cross_checks.EarlierFitThresholds | None = None,
               review_pre_annotation_fit: bool = False) -> Fit:
    """Store a fit of a sample in 'fitting' and route it: heuristic accept (D^h) when a prediction passes
    all criteria, or a pre-annotation's fit passes them with the detector in MVNet's role (`detector_thresholds`;
    None: detector fits are never accepted without a person); straight to review when fitted from annotations;
    else 'fitted', awaiting the reviewer queue policy. `vertices_m` (V, 3) metres, world frame: the fitted mesh as
    the worker posed it, stored with the fit so the API shows it without posing the hand again (float32).
    A fit from a prediction that fails the paper's heuristic is accepted when it passes `cross_thresholds` against the
    detector's lift left by the sample's pre-annotation; else the sample is accepted with that pre-annotation's fit
    when it passes `earlier_fit_thresholds` against MVNet's prediction (None: that check is off;
    workers.tasks.cross_checks). With `review_pre_annotation_fit`, a fit from a prediction that nothing accepted leaves
    the sample's pre-annotation fit (if no person decided on it) as the one the reviewers see."""
    theta = _finite_array(params, (NUM_PARAMS,), "params")
    kp = _finite_array(keypoints_m, (NUM_KEYPOINTS, 3), "keypoints_m")
    vertices = None
    if vertices_m is not None:
        vertices = _finite_array(vertices_m, (len(vertices_m), 3), "vertices_m")
        if not len(vertices):
            raise InvalidInputError("vertices_m must hold at least one vertex")
    if job_id is not None and jobs.is_final(session, job_id):
        raise ConflictError(f"job {job_id} is already finished or cancelled; fit not recorded")
    sample = queues.load_locked(session, sample_id)
    if sample.state != SampleState.fitting:
        raise ConflictError(f"sample {sample_id} is '{sample.state}', not 'fitting'; fit not recorded")
    known_views = {v.id for v in views_of(session, sample_id, with_masks=False)}
    ious = {int(k): float(v) for k, v in view_ious.items()}
    if unknown := set(ious) - known_views:
        raise InvalidInputError(f"view_ious name views {sorted(unknown)} that are not views of sample {sample_id}")
    if not all(np.isfinite(v) and 0 <= v <= 1 for v in ious.values()):
        raise InvalidInputError("view_ious must lie in [0, 1]")
    prediction = session.get(Prediction, prediction_id) if prediction_id is not None else None
    if prediction_id is not None and (prediction is None or prediction.sample_id != sample_id):
        raise InvalidInputError(f"prediction {prediction_id} does not belong to sample {sample_id}")
    articulation = HandParams.from_theta(theta).pose
    fit = Fit(sample_id=sample_id, job_id=job_id, prediction_id=prediction_id, params=theta.tolist(),
              keypoints_m=kp.tolist(), view_ious={str(k): v for k, v in ious.items()}, diagnostics=diagnostics,
              inputs=inputs, model_file=model_file, pose_distance=float(np.linalg.norm(articulation)),
              round_id=rounds.open_round_id(session),
              vertices_f32=None if vertices is None else vertices.astype("<f4").tobytes())
    session.add(fit)
    session.flush()
    sample.current_fit_id = fit.id
    sample.pose_distance = fit.pose_distance
    transition(session, sample, SampleState.fitted, None, reason=f"fit {fit.id}")
    if job_id is not None:
        jobs.finish(session, job_id, JobState.succeeded, result={"fit_id": fit.id})

    estimator, label = MVNET, fit
    detection = cross_checks.detection_of(fit)
    if prediction is not None and ious:
        verdict = heuristic_verdict(prediction.confidences, ious.values(), prediction.keypoints_m, fit.keypoints_m,
                                    thresholds)
        fit.heuristic = _record(verdict, inputs, MVNET)
        if not verdict.accepted:
            checked = cross_thresholds is not None or earlier_fit_thresholds is not None or review_pre_annotation_fit
            earlier = cross_checks.pre_annotation_fit(session, fit) if checked else None
            estimator, label = _cross_check(fit, earlier, prediction, ious, cross_thresholds, earlier_fit_thresholds)
            if estimator == MVNET and review_pre_annotation_fit and earlier is not None:
                _show_pre_annotation_fit(sample, fit, earlier)
    elif detector_thresholds is not None and ious and detection is not None:
        estimator = DETECTOR_SOURCE
        verdict = cross_checks.against_lift(fit, detection, ious, detector_thresholds)
        if verdict is not None:
            fit.heuristic = _record(verdict, inputs, DETECTOR_SOURCE)
    if fit.heuristic is not None and fit.heuristic["accepted"]:
        if label is not fit:  # the pre-annotation's fit is the label
            sample.current_fit_id, sample.pose_distance = label.id, label.pose_distance
        transition(session, sample, SampleState.accepted, None, reason="heuristic")
        round_ = rounds.open_round(session, None)
        session.add(Decision(sample_id=sample_id, fit_id=label.id, round_id=round_.id, by_heuristic=True,
                             decision=DecisionKind.accept, reason=f"heuristic ({ESTIMATOR_NAMES[estimator]}): "
                                                                  "all criteria met"))
        rounds.add_member(session, round_, sample_id, label.id, Stream.heuristic)
        label_audits.schedule(session, round_, sample_id, label.id, Stream.heuristic, None)
    elif fit.heuristic is None and inputs.get("submission_ids") and not agreement.route(session, sample, fit):
        # issue 40's second looks
        transition(session, sample, SampleState.in_review, None, reason="fitted from annotations")
    audit.record(session, None, "fit.create", "sample", sample_id, fit_id=fit.id, state=sample.state)
    return fit


def _show_pre_annotation_fit(sample: Sample, fit: Fit, earlier: Fit) -> None:
    """The reviewers see the sample's pre-annotation fit `earlier` instead of MVNet's `fit` (recorded in
    fit.heuristic as "reviewed_fit_id"): where no heuristic took MVNet's fit, round 0's fit from the detector's
    keypoints and the chroma key is the likelier to be right (docs/evaluation.md, "Cross-estimator checks"). The
    reviewer still decides."""
    sample.current_fit_id, sample.pose_distance = earlier.id, earlier.pose_distance
    fit.heuristic = {**(fit.heuristic or {}), "reviewed_fit_id": earlier.id}


def _record(verdict: HeuristicResult, inputs: dict[str, Any], estimator: str) -> dict[str, Any]:
    """fit.heuristic: the verdict, its metrics (what the precision target learns from), what the IoU compared."""
    return {"accepted": verdict.accepted, "failed": list(verdict.failed), **verdict.metrics,
            "iou_reference": iou_reference(inputs), "estimator": estimator}


def _cross_check(fit: Fit, earlier: Fit | None, prediction: Prediction, ious: Mapping[int, float],
                 cross_thresholds: HeuristicThresholds | None,
                 earlier_fit_thresholds: cross_checks.EarlierFitThresholds | None
                 ) -> tuple[str, Fit]:
    """After the paper's heuristic failed MVNet's `fit`: the two cross-estimator checks against the sample's
    pre-annotation (workers.tasks.cross_checks), the pre-annotation's fit against MVNet's prediction first, then MVNet's
    fit against the lift; each recorded in fit.heuristic ("earlier_fit", "cross"). Returns
    the estimator that accepted and the fit to label the sample with, or (MVNET, fit) when neither did. `earlier`: the
    sample's pre-annotation fit no person decided on (cross_checks.pre_annotation_fit), or None."""
    if earlier is None or (cross_thresholds is None and earlier_fit_thresholds is None):
        return MVNET, fit
    record = dict(fit.heuristic)
    outcome: tuple[str, Fit] = (MVNET, fit)
    # The pre-annotation's fit first: where both pass it is usually the better label (made with the detector's
    # keypoints and the chroma key; on tuning seed 11 it was nearer the truth than MVNet's fit for 63 of 92 samples).
    other = (cross_checks.earlier_fit_against_prediction(earlier, prediction, earlier_fit_thresholds)
             if earlier_fit_thresholds is not None else None)
    if other is not None:
        record["earlier_fit"] = {"accepted": other.accepted, "failed": list(other.failed), "fit_id": earlier.id,
                                 **other.metrics}
        if other.accepted:
            outcome = (EARLIER_FIT, earlier)
    if outcome[0] == MVNET and cross_thresholds is not None:
        cross = cross_checks.fit_against_lift(earlier, fit, ious, cross_thresholds)
        if cross is not None:
            record["cross"] = {"accepted": cross.accepted, "failed": list(cross.failed), **cross.metrics}
            if cross.accepted:
                outcome = (CROSS, fit)
    record["accepted"], record["estimator"] = outcome[0] != MVNET, outcome[0]
    fit.heuristic = record
    return outcome


def iou_reference(inputs: dict[str, Any]) -> str:
    """What the heuristic's IoU compared the fit with, from the fit's inputs: "chroma_key_cut" (chroma-key
    masks cut at the predicted wrist), "handsegnet", "chroma_key" (cut at the fit's wrist, when HandSegNet
    found no hand), or "mixed" (per view in inputs["iou_reference"])."""
    per_view = set((inputs.get("iou_reference") or {}).values())
    if len(per_view) == 1:
        return str(per_view.pop())
    return "mixed" if per_view else str(inputs.get("mask_source", "handsegnet"))


def record_fit_failure(session: Session, sample_id: int, job_id: int | None, error: str) -> None:
    """A fit that could not be made sends the sample back to the annotators (a redelivered failure, or one
    for a job already finished or cancelled, changes nothing)."""
    if job_id is not None and jobs.is_final(session, job_id):
        return
    sample = queues.load_locked(session, sample_id)
    if job_id is not None:
        jobs.finish(session, job_id, JobState.failed, error=error)
    fit_samples.release_failed_fit(session, sample, error)
