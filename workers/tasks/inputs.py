"""Loading what the compute needs from the database and storage: a project's rig, a sample's frame (as the
capture reader's `FrameRef`, pointing at the stored files), clicks and masks for a fit from annotations,
MVNet keypoints and HandSegNet masks for a fit from predictions.

Every loader raises `InputError` naming the sample, view or row at fault; the fit service turns it into
a recorded fit failure for that one sample.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import CameraCalibration, Sample, Sequence, View
from backend.models.enums import MaskKind, Visibility
from backend.models.fits import Prediction
from backend.models.jobs import Job
from backend.models.labels import Click, Mask, Submission
from workers.capture.schema import Capture, FrameRef, HandModelInfo
from workers.fitting.inputs import OCCLUDED_CLICK_WEIGHT, PROPOSAL_CLICK_WEIGHT, FrameObservations
from workers.fitting.reference_masks import prediction_reference_masks
from workers.geometry.camera import Camera
from workers.tasks.context import WorkerContext

NUM_KEYPOINTS = 21
CLICK_WEIGHT = {Visibility.visible.value: 1.0, Visibility.occluded.value: OCCLUDED_CLICK_WEIGHT,
                Visibility.not_annotated.value: 0.0}


class InputError(ValueError):
    """The stored data cannot make this input; the message names the row or file at fault."""


@dataclass(frozen=True, eq=False)
class Rig:
    """A project's calibrated cameras in calibration order (the order of every per-view array)."""

    project_id: int
    cameras: tuple[Camera, ...]
    camera_ids: tuple[int, ...]
    digest: str  # identifies the calibration, for caches keyed by rig


@dataclass(frozen=True, eq=False)
class SampleFrame:
    """One sample with its views in rig order."""

    sample_id: int
    project_id: int
    sequence_key: str  # the sequence's external id
    frame_index: int
    time_s: float
    state: str
    view_ids: tuple[int, ...]
    frame: FrameRef  # image and chroma-key mask files in storage; no ground truth (never used for labels)
    side: str = "right"  # the sequence's hand: which hand model fits it


def load_rig(session: Session, project_id: int) -> Rig:
    rows = session.execute(select(CameraCalibration).where(CameraCalibration.project_id == project_id)
                           .order_by(CameraCalibration.id)).scalars().all()
    if not rows:
        raise InputError(f"project {project_id} has no camera calibration")
    cameras = tuple(Camera(r.name, r.width, r.height, np.asarray(r.K), np.asarray(r.dist), np.asarray(r.R),
                           np.asarray(r.t)) for r in rows)
    blob = json.dumps([[r.name, r.width, r.height, r.K, r.dist, r.R, r.t] for r in rows]).encode()
    return Rig(project_id, cameras, tuple(r.id for r in rows), hashlib.sha1(blob).hexdigest()[:16])


def rig_of(ctx: WorkerContext, session: Session, project_id: int) -> Rig:
    """The rig, cached per process (calibrations do not change after import)."""
    return ctx.cached(("rig", ctx.settings.resolved_database_url, project_id), lambda: load_rig(session, project_id))


def capture_for(rig: Rig, root: Path, name: str = "database") -> Capture:
    """A `Capture` record around stored frames, for the networks' dataset builders (they read its cameras)."""
    return Capture(root=root, name=name, cameras=rig.cameras, subjects={}, sequences=(),
                   hand_model=HandModelInfo(name="unknown", is_mano=False), synthetic=False)


def load_frames(ctx: WorkerContext, session: Session, sample_ids: list[int]) -> dict[int, SampleFrame]:
    """Frames of these samples (missing ids are left out). One query for samples, one for views and
    cameras, one for chroma-key masks."""
    if not sample_ids:
        return {}
    samples = session.execute(
        select(Sample.id, Sample.frame_index, Sample.time_s, Sample.state, Sequence.project_id, Sequence.external_id,
               Sequence.side)
        .join(Sequence, Sequence.id == Sample.sequence_id).where(Sample.id.in_(sample_ids))
    ).all()
    views = session.execute(
        select(View.sample_id, View.id, View.camera_id, View.image_key).where(View.sample_id.in_(sample_ids))
    ).all()
    by_sample: dict[int, dict[int, tuple[int, str]]] = {}
    for sample_id, view_id, camera_id, image_key in views:
        by_sample.setdefault(sample_id, {})[camera_id] = (view_id, image_key)
    view_ids = [v[1] for v in views]
    chroma = dict(session.execute(
        select(Mask.view_id, Mask.storage_key).where(Mask.view_id.in_(view_ids), Mask.kind == MaskKind.chroma_key)
        .order_by(Mask.version)
    ).all()) if view_ids else {}
    out: dict[int, SampleFrame] = {}
    for sample_id, frame_index, time_s, state, project_id, sequence_key, side in samples:
        rig = rig_of(ctx, session, project_id)
        have = by_sample.get(sample_id, {})
        missing = [cam.name for cam, cid in zip(rig.cameras, rig.camera_ids, strict=True) if cid not in have]
        if missing:
            raise InputError(f"sample {sample_id} has no view of camera(s) {missing}")
        ordered = [have[cid] for cid in rig.camera_ids]
        image_paths = {cam.name: ctx.storage_path(key) for cam, (_, key) in zip(rig.cameras, ordered, strict=True)}
        mask_paths = {cam.name: ctx.storage_path(chroma[vid])
                      for cam, (vid, _) in zip(rig.cameras, ordered, strict=True) if vid in chroma}
        if mask_paths and len(mask_paths) != len(rig.cameras):
            mask_paths = {}  # the transport of alphas needs all views or none
        frame = FrameRef(sequence_id=sequence_key, index=frame_index, time_s=time_s, image_paths=image_paths,
                         mask_paths=mask_paths, ground_truth_path=None)
        out[sample_id] = SampleFrame(sample_id, project_id, sequence_key, frame_index, time_s, state,
                                     tuple(v for v, _ in ordered), frame, side)
    return out


def read_mask(ctx: WorkerContext, key: str, shape: tuple[int, int], what: str) -> np.ndarray:
    """A stored mask (8-bit PNG, any filter) as (H, W) bool; InputError if unreadable or of another size."""
    path = ctx.storage_path(key)
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f"{what}: mask file {key!r} is missing or unreadable")
    if image.shape != shape:
        raise InputError(f"{what}: mask {key!r} is {image.shape[1]}x{image.shape[0]}, "
                         f"the view is {shape[1]}x{shape[0]}")
    return image >= 128


# --- fit inputs -------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FitInput:
    """Everything one fit needs, and what its Fit row records about where it came from."""

    job_id: int
    sample_id: int
    source: str  # "annotation", "prediction" or "detector"
    rig: Rig
    view_ids: tuple[int, ...]
    observations: FrameObservations
    inputs: dict[str, Any]
    prediction_id: int | None = None
    round_id: int | None = None
    side: str = "right"  # the sample's sequence's hand: the hand model the fit uses


def _submission_of(session: Session, job: Job) -> Submission:
    submission = session.execute(select(Submission).where(Submission.fit_job_id == job.id)).scalar_one_or_none()
    client_id = (job.payload or {}).get("client_submission_id")
    if submission is None and client_id:
        submission = session.execute(select(Submission).where(Submission.client_id == client_id)).scalar_one_or_none()
    if submission is None:
        raise InputError(f"fit job {job.id}: no submission of clicks belongs to it")
    return submission


def click_weight(visibility: str, from_proposal: bool) -> float:
    """A stored click's weight in the fit: by its visibility, lower for a point accepted from a proposal
    (PROPOSAL_CLICK_WEIGHT: it is the proposal's evidence, not a person's placement)."""
    weight = CLICK_WEIGHT.get(visibility, 0.0)
    return weight * PROPOSAL_CLICK_WEIGHT if from_proposal else weight


def from_annotation(ctx: WorkerContext, session: Session, job: Job, frame: SampleFrame, rig: Rig) -> FitInput:
    """Clicks of the job's submission (points accepted from proposals weighed as such, `click_weight`); per
    view the newest corrected mask, else the chroma-key mask."""
    submission = _submission_of(session, job)
    C = len(rig.cameras)
    column = {view_id: c for c, view_id in enumerate(frame.view_ids)}
    clicks = np.full((C, NUM_KEYPOINTS, 2), np.nan)
    weights = np.zeros((C, NUM_KEYPOINTS))
    accepted = np.zeros((C, NUM_KEYPOINTS), dtype=bool)
    for click in session.execute(select(Click).where(Click.submission_id == submission.id)).scalars():
        c = column.get(click.view_id)
        if c is None:
            raise InputError(f"submission {submission.id}: click on view {click.view_id}, not a view of the sample")
        weight = click_weight(click.visibility, bool(click.from_proposal))
        if weight > 0 and click.x_px is not None and click.y_px is not None:
            clicks[c, click.keypoint] = (click.x_px, click.y_px)
            weights[c, click.keypoint] = weight
            accepted[c, click.keypoint] = bool(click.from_proposal)
    masks, mask_ids = [], []
    newest = newest_masks(session, list(frame.view_ids), (MaskKind.corrected, MaskKind.chroma_key))
    for c, (view_id, cam) in enumerate(zip(frame.view_ids, rig.cameras, strict=True)):
        row = newest.get(view_id)
        if row is None:
            masks.append(None)
            continue
        masks.append(read_mask(ctx, row.storage_key, (cam.height, cam.width), f"sample {frame.sample_id} view {c}"))
        mask_ids.append(row.id)
    observations = FrameObservations(clicks, weights, masks=tuple(masks) if any(m is not None for m in masks) else None,
                                     masks_include_forearm=True, from_proposal=accepted)
    used = weights > 0
    inputs = {"source": "annotation", "submission_ids": [submission.id], "mask_ids": mask_ids,
              "clicks": int(used.sum()), "clicked": int((used & ~accepted).sum()),
              "accepted_proposals": int((used & accepted).sum()), "proposal_weight": PROPOSAL_CLICK_WEIGHT}
    return FitInput(job.id, frame.sample_id, "annotation", rig, frame.view_ids, observations, inputs,
                    round_id=job.round_id)


def newest_masks(session: Session, view_ids: list[int], kinds: tuple[MaskKind, ...]) -> dict[int, Mask]:
    """Per view the newest mask of the first kind in `kinds` that the view has."""
    rows = session.execute(select(Mask).where(Mask.view_id.in_(view_ids), Mask.kind.in_([k.value for k in kinds]))
                           .order_by(Mask.version)).scalars().all()
    rank = {k.value: i for i, k in enumerate(kinds)}
    best: dict[int, Mask] = {}
    for row in rows:  # ascending versions: later rows of the same rank replace earlier ones
        current = best.get(row.view_id)
        if current is None or rank[row.kind] <= rank[current.kind]:
            best[row.view_id] = row
    return best


def from_prediction(ctx: WorkerContext, session: Session, job: Job, frame: SampleFrame, rig: Rig) -> FitInput:
    """MVNet's 3D keypoints weighted by their confidences, and per view the mask the fit's silhouette (and so
    the heuristic's IoU) is compared with: HandSegNet's (hand-only) mask; with the setting
    `heuristic_iou_reference` = "chroma_key", on views with a chroma-key mask, that mask cut at MVNet's
    predicted wrist instead (see `prediction_reference_masks`)."""
    prediction_id = (job.payload or {}).get("prediction_id")
    prediction = session.get(Prediction, prediction_id) if prediction_id is not None else None
    if prediction is None or prediction.sample_id != frame.sample_id:
        raise InputError(f"fit job {job.id}: prediction {prediction_id} of sample {frame.sample_id} not found")
    keypoints = np.asarray(prediction.keypoints_m, dtype=np.float64)
    confidences = np.asarray(prediction.confidences, dtype=np.float64)
    keys = {view_id: f"masks/predicted/{view_id}/{prediction.id}.png" for view_id in frame.view_ids}
    stored = dict(session.execute(select(Mask.storage_key, Mask.id).where(
        Mask.view_id.in_(list(frame.view_ids)), Mask.kind == MaskKind.predicted,
        Mask.storage_key.in_(list(keys.values())))).all())
    predicted: list[np.ndarray | None] = []
    predicted_ids: list[int | None] = []
    for c, (view_id, cam) in enumerate(zip(frame.view_ids, rig.cameras, strict=True)):
        key = keys[view_id]
        if key not in stored:
            predicted.append(None)
            predicted_ids.append(None)
            continue
        predicted.append(read_mask(ctx, key, (cam.height, cam.width), f"sample {frame.sample_id} view {c}"))
        predicted_ids.append(stored[key])
    chroma_rows = newest_masks(session, list(frame.view_ids), (MaskKind.chroma_key,))
    use_chroma = ctx.settings.heuristic_iou_reference == "chroma_key"
    if use_chroma or not any(i is not None for i in predicted_ids):
        chroma = [read_mask(ctx, chroma_rows[v].storage_key, (cam.height, cam.width),
                            f"sample {frame.sample_id} view {c}") if v in chroma_rows else None
                  for c, (v, cam) in enumerate(zip(frame.view_ids, rig.cameras, strict=True))]
    else:
        chroma = [None] * len(frame.view_ids)
    C = len(rig.cameras)
    masks, sources, include_forearm = prediction_reference_masks(predicted, chroma, rig.cameras, keypoints,
                                                                 ctx.settings.heuristic_iou_reference)
    ids = {"chroma_key_cut": [chroma_rows[v].id if v in chroma_rows else None for v in frame.view_ids],
           "chroma_key": [chroma_rows[v].id if v in chroma_rows else None for v in frame.view_ids],
           "handsegnet": predicted_ids}
    mask_ids = [ids[src][c] for c, src in enumerate(sources) if src is not None]
    kinds = {s for s in sources if s is not None}
    mask_source = kinds.pop() if len(kinds) == 1 else ("mixed" if kinds else "none")
    observations = FrameObservations(np.full((C, NUM_KEYPOINTS, 2), np.nan), np.zeros((C, NUM_KEYPOINTS)),
                                     masks=tuple(masks) if mask_ids else None, masks_include_forearm=include_forearm,
                                     keypoints_3d=keypoints, keypoint_3d_weights=np.clip(confidences, 0, 1))
    # iou_reference: per view (rig order) what the fit's silhouette, hence the heuristic's IoU, is compared with.
    inputs = {"source": "prediction", "prediction_id": prediction.id, "mask_ids": mask_ids, "mask_source": mask_source,
              "iou_reference": {str(v): s for v, s in zip(frame.view_ids, sources, strict=True) if s is not None},
              "mvnet_version": prediction.mvnet_version, "handsegnet_version": prediction.handsegnet_version}
    return FitInput(job.id, frame.sample_id, "prediction", rig, frame.view_ids, observations, inputs,
                    prediction_id=prediction.id, round_id=job.round_id)


