"""Pre-annotation's detections as fit input: the detector's output for a frame as stored in a fit job's payload
(and the fit's inputs), and the fit input made from it (a fit job of source "detector").

Below both the pre-annotation job (workers.tasks.preannotate), which records detections, and the fit input
of every fit job (workers.tasks.fit_sources), which reads them back.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from backend.models.enums import MaskKind
from backend.models.jobs import Job
from workers.detector.handedness import lifted_side
from workers.detector.types import DetectorInputError, LiftedKeypoints
from workers.detector.usable import used_detections
from workers.fitting.inputs import FrameObservations
from workers.geometry.camera import Camera
from workers.tasks.context import WorkerContext
from workers.tasks.inputs import NUM_KEYPOINTS, FitInput, InputError, Rig, SampleFrame, newest_masks, read_mask
from workers.tasks.json_values import json_safe

SOURCE = "detector"  # the fit source and the proposal kind


def detection_record(lifted: LiftedKeypoints, view_ids: Sequence[int]) -> dict[str, Any]:
    """The detector's output for one frame as JSON (NaN -> None): what the fit is made from and what the
    annotators' "D" proposals show. Per-view arrays follow `view_ids` (calibration order). "hand_side" is the side
    the detected hand looks like (workers.detector.handedness.lifted_side; None where unclear), per view
    "right_score" the model's own handedness."""
    C = len(view_ids)
    inliers = np.asarray(lifted.inliers, dtype=bool)
    if inliers.shape != (NUM_KEYPOINTS, C) or len(lifted.views) != C:
        raise DetectorInputError(f"the detector answered for {len(lifted.views)} views (inliers {inliers.shape}); "
                                 f"the sample has {C}")
    # Rounded far below what the detector resolves (0.01 px, 1 um, 1e-4): a record per sample is stored twice
    # (the fit job's payload, the fit's inputs), so its size counts.
    def rounded(value: Any, shape: tuple[int, ...], decimals: int) -> np.ndarray:
        return np.round(np.asarray(value, dtype=np.float64).reshape(shape), decimals)

    views = []
    for view_id, view in zip(view_ids, lifted.views, strict=True):
        views.append(None if view is None else {
            "view_id": int(view_id), "keypoints_px": rounded(view.keypoints_px, (NUM_KEYPOINTS, 2), 2),
            "scores": rounded(view.scores, (NUM_KEYPOINTS,), 4), "presence": round(float(view.presence), 4),
            "handedness": view.handedness, "right_score": round(float(view.right_score), 4),
            "box_px": rounded(view.box_px, (4,), 2), "rotation_rad": round(float(view.rotation_rad), 4)})
    return json_safe({
        "view_ids": [int(v) for v in view_ids], "views": views,
        "points_world": rounded(lifted.points_world, (NUM_KEYPOINTS, 3), 6),
        "confidence": rounded(lifted.confidence, (NUM_KEYPOINTS,), 4),
        "reprojection_px": rounded(lifted.reprojection_px, (NUM_KEYPOINTS,), 2),
        "inliers": inliers.tolist(), "frame_confidence": round(float(lifted.frame_confidence), 4),
        "hand_side": lifted_side(lifted)})


def _floats(value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A JSON list (None = NaN) as a float array of `shape`; InputError when it is not one."""
    try:
        array = np.array(value, dtype=np.float64)  # None -> nan
    except (TypeError, ValueError) as exc:
        raise InputError(f"stored detection is not numeric: {exc}") from exc
    if array.shape != shape:
        raise InputError(f"stored detection has shape {array.shape}, expected {shape}")
    return array


def lifted_count(record: dict[str, Any]) -> int:
    """How many keypoints the detection lifted to 3D."""
    return int(np.isfinite(_floats(record.get("points_world"), (NUM_KEYPOINTS, 3))).all(1).sum())


def observations_from_detection(record: dict[str, Any], cameras: Sequence[Camera],
                                masks: Sequence[np.ndarray | None] | None) -> FrameObservations:
    """Fit input from a detection record: per view and keypoint the detection where that view is an inlier of the
    keypoint's triangulation, weighted by its score (clipped to [0, 1]) times the view's presence; keypoints
    outside the image are left out. The lifted 3D keypoints (weighted by their confidence) place the hand
    initially; the round-0 weights give them no loss term (`LossWeights().kp3d == 0`). Where the frame has masks,
    the fit weighs the 2D keypoints low against the silhouettes (`LossWeights.detector_with_silhouettes`).

    Args:
        record: `detection_record` output.
        cameras: the C cameras of the rig, calibration order.
        masks: per view (H, W) bool or None (foreground masks that include the forearm), or None.
    """
    C = len(cameras)
    inliers = np.asarray(record.get("inliers"), dtype=bool)
    views = record.get("views") or []
    if inliers.shape != (NUM_KEYPOINTS, C) or len(views) != C:
        raise InputError(f"stored detection covers {len(views)} views; the rig has {C}")
    clicks = np.full((C, NUM_KEYPOINTS, 2), np.nan)
    weights = np.zeros((C, NUM_KEYPOINTS))
    for c, (view, cam) in enumerate(zip(views, cameras, strict=True)):
        if view is None:
            continue
        xy = _floats(view.get("keypoints_px"), (NUM_KEYPOINTS, 2))
        scores = np.nan_to_num(_floats(view.get("scores"), (NUM_KEYPOINTS,)), nan=0.0)
        presence = float(np.clip(np.nan_to_num(float(view.get("presence") or 0.0)), 0.0, 1.0))
        use = used_detections(xy, scores, presence, inliers[:, c], cam.width, cam.height)
        clicks[c, use] = xy[use]
        weights[c, use] = np.clip(scores[use], 0.0, 1.0) * presence
    points = _floats(record.get("points_world"), (NUM_KEYPOINTS, 3))
    confidence = np.nan_to_num(_floats(record.get("confidence"), (NUM_KEYPOINTS,)), nan=0.0)
    lifted = np.isfinite(points).all(1)
    keypoint_weights = np.where(lifted, np.clip(confidence, 0.0, 1.0), 0.0)
    return FrameObservations(clicks, weights, masks=tuple(masks) if masks is not None else None,
                             masks_include_forearm=True, keypoints_3d=np.where(lifted[:, None], points, np.nan),
                             keypoint_3d_weights=keypoint_weights, points_source="detector")


def masks_for(ctx: WorkerContext, session: Session, frame: SampleFrame, rig: Rig
               ) -> tuple[list[np.ndarray | None], list[int]]:
    """Per view the newest corrected mask, else the chroma-key mask (as the annotation fits use), and their ids."""
    newest = newest_masks(session, list(frame.view_ids), (MaskKind.corrected, MaskKind.chroma_key))
    masks: list[np.ndarray | None] = []
    ids: list[int] = []
    for c, (view_id, cam) in enumerate(zip(frame.view_ids, rig.cameras, strict=True)):
        row = newest.get(view_id)
        if row is None:
            masks.append(None)
            continue
        masks.append(read_mask(ctx, row.storage_key, (cam.height, cam.width), f"sample {frame.sample_id} view {c}"))
        ids.append(row.id)
    return masks, ids


def fit_input_from_detection(ctx: WorkerContext, session: Session, job: Job, frame: SampleFrame, rig: Rig
                             ) -> FitInput:
    """The fit input of a fit job of source "detector" (its payload holds the detection)."""
    payload = job.payload or {}
    record = payload.get("detection")
    if not isinstance(record, dict):
        raise InputError(f"fit job {job.id}: no detection in its payload")
    if [int(v) for v in record.get("view_ids", [])] != list(frame.view_ids):
        raise InputError(f"fit job {job.id}: the detection's views {record.get('view_ids')} are not the sample's "
                         f"{list(frame.view_ids)}")
    masks, mask_ids = masks_for(ctx, session, frame, rig)
    observations = observations_from_detection(record, rig.cameras, masks if mask_ids else None)
    inputs = {"source": SOURCE, "preannotate_job_id": payload.get("preannotate_job_id"), "mask_ids": mask_ids,
              "keypoints_2d": int((observations.click_weights > 0).sum()), "detection": record,
              "detector_confidence": record.get("frame_confidence")}
    return FitInput(job.id, frame.sample_id, SOURCE, rig, frame.view_ids, observations, inputs, round_id=job.round_id)
