"""What the annotate and review pages draw over the views: calibrations, proposals, the fit's
keypoints and mesh, per-view IoU and residuals.

Reads only; each payload is for a sample whose lease the caller holds (the one on screen or the one
prefetched), so the role rules and the queues decide who sees what, as for the tasks themselves.
"""

from __future__ import annotations

import base64
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session, undefer

from backend.models.agreement import AgreementPair
from backend.models.enums import DecisionKind, LeaseKind
from backend.models.fits import Fit, Prediction
from backend.models.labels import Click, Submission
from backend.models.review import Decision
from backend.services.accounts.users import Actor
from backend.services.captures.samples import get_sample
from backend.services.display import scene_tickets
from backend.services.display.detection_points import SOURCE as DETECTOR_SOURCE
from backend.services.display.detection_points import fitted_detections
from backend.services.display.fit_agreement import fit_confidences
from backend.services.display.view_geometry import ViewCamera, pixels_or_none, view_cameras
from backend.services.errors import ConflictError, NotFoundError
from backend.services.leases import queues
from backend.services.leases.annotation_flags import last_fit_failure
from backend.viewer.hand_mesh import fit_mesh, fit_side, hand_model_label, is_stand_in, load_arrays
from backend.viewer.scene import viewpoint
from workers.geometry.projection import project_visible
from workers.handmodel.keypoints import SKELETON_EDGES, SPARSE_KEYPOINTS
from workers.handmodel.posed import HandMesh

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClickRow:
    view_id: int
    keypoint: int
    x: float | None
    y: float | None
    visibility: str
    from_proposal: bool = False  # accepted from a proposal, not placed by hand

    def to_public(self) -> dict[str, Any]:
        return {"view_id": self.view_id, "keypoint": self.keypoint, "x": self.x, "y": self.y,
                "visibility": self.visibility, "from_proposal": self.from_proposal}


def end_reads(session: Session) -> None:
    """End a read-only transaction before the CPU work (projections, meshes, images), so the request holds
    no database connection (nor, on SQLite, a WAL snapshot) while it computes. Nothing was written; the rows
    read stay loaded (expire_on_commit=False)."""
    if session.new or session.dirty or session.deleted:
        raise RuntimeError("end_reads on a session with pending changes")
    session.commit()


def _held(session: Session, user: Actor, sample_id: int, kind: LeaseKind):
    sample = get_sample(session, sample_id)
    queues.check_lease(sample, user, kind, None)
    return sample


def clicks_of(session: Session, sample_id: int, submission_ids: list[int] | None = None) -> list[ClickRow]:
    """The clicks a fit used (its submissions; the newest one wins per view and keypoint), or those of
    the sample's newest submission."""
    if not submission_ids:
        newest = session.execute(select(Submission.id).where(Submission.sample_id == sample_id)
                                 .order_by(Submission.id.desc()).limit(1)).scalar_one_or_none()
        submission_ids = [] if newest is None else [newest]
    if not submission_ids:
        return []
    rows = session.execute(
        select(Click.view_id, Click.keypoint, Click.x_px, Click.y_px, Click.visibility, Click.from_proposal)
        .where(Click.sample_id == sample_id, Click.submission_id.in_([int(i) for i in submission_ids]))
        .order_by(Click.submission_id, Click.id)
    ).all()
    latest = {(r.view_id, r.keypoint): ClickRow(*r[:5], from_proposal=bool(r.from_proposal)) for r in rows}
    return list(latest.values())


def newest_prediction(session: Session, sample_id: int) -> Prediction | None:
    return session.execute(select(Prediction).where(Prediction.sample_id == sample_id)
                           .order_by(Prediction.id.desc()).limit(1)).scalar_one_or_none()


def _projections(points_m: Any, cameras: list[ViewCamera]) -> dict[int, np.ndarray]:
    points = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    return {cam.view_id: project_visible(points, cam) for cam in cameras}


def annotate_proposals(session: Session, user: Actor, sample_id: int, *, mano_path: Path | None = None
                       ) -> dict[str, Any]:
    """Calibrations (the browser triangulates from the annotator's own clicks), proposal sources in the order the
    page offers them (the first one holding a point wins): for a pre-annotation fit its keypoints, then the
    detector's behind it; else MVNet's prediction, then the current fit; each projected into every view. Also the
    previous clicks and the reviewer's note when the sample came back from review. The fit's source also says per
    view which keypoints its mesh hides (`hidden`): Enter accepts those as occluded (docs/ui.md)."""

    sample = _held(session, user, sample_id, LeaseKind.annotate)
    cameras = view_cameras(session, sample_id)
    prediction = newest_prediction(session, sample_id)
    fit = (session.get(Fit, sample.current_fit_id, options=[undefer(Fit.vertices_f32)])
           if sample.current_fit_id is not None else None)
    note = session.execute(
        select(Decision.reason).where(Decision.sample_id == sample_id, Decision.decision == DecisionKind.annotate)
        .order_by(Decision.id.desc()).limit(1)).scalar_one_or_none()
    # blind (issue 40): a sample waiting for its agreement second look shows none of the first look's clicks
    second_look = session.execute(select(AgreementPair.id).where(AgreementPair.sample_id == sample_id,
                                                                 AgreementPair.state == "second_look")).first()
    previous = [] if second_look is not None else clicks_of(session, sample_id)
    fit_failure = last_fit_failure(session, sample)
    end_reads(session)
    sources = []
    fitted = None
    if fit is not None:
        projected = _projections(fit.keypoints_m, cameras)
        # F's confidence: the fit's agreement with what it was fitted to, per keypoint (services.display.fit_agreement).
        observed = fitted_detections(fit.inputs, cameras)
        if observed is None:
            observed = {}
            for c in previous:
                if c.x is not None and c.y is not None and not c.from_proposal:
                    observed.setdefault(c.view_id, {})[c.keypoint] = (c.x, c.y)
        fitted = {"kind": "fit", "label": f"fit {fit.id} ({hand_model_label(fit.model_file)})",
                  "confidences": fit_confidences(projected, observed),
                  "views": {str(v): pixels_or_none(p) for v, p in projected.items()},
                  "hidden": hidden_keypoints(fit, cameras, mano_path)}
    detection = detector_proposal(fit, cameras) if fit is not None else None
    if detection is not None:
        # The fit of the detector's keypoints first: one hand agreeing with all views and the hand's anatomy lies
        # nearer the truth than a view's own detection, even where a reviewer sent the fit back (docs/detector.md).
        sources += [fitted, detection]
    if prediction is not None:
        projected = _projections(prediction.keypoints_m, cameras)
        sources.append({"kind": "mvnet", "label": f"MVNet {prediction.mvnet_version}",
                        "confidences": [round(float(c), 4) for c in prediction.confidences],
                        "views": {str(v): pixels_or_none(p) for v, p in projected.items()}})
    if fitted is not None and detection is None:
        sources.append(fitted)
    return {"sample_id": sample_id, "cameras": [c.to_public() for c in cameras],
            "keypoints_to_click": list(SPARSE_KEYPOINTS), "sources": sources,
            "previous_clicks": [c.to_public() for c in previous], "review_note": note,
            "fit_failure": fit_failure}


def hidden_keypoints(fit: Fit, cameras: list[ViewCamera], mano_path: Path | None) -> dict[str, list[bool]] | None:
    """View id -> (21,) whether the fit's own mesh hides each of its keypoints from that camera (the hand's
    self-occlusion; a held object is not in the mesh); None when this server cannot pose the fit's hand model."""
    arrays = load_arrays(fit.model_file, mano_path, fit_side(fit.diagnostics))
    if arrays is None or fit.params is None:
        return None
    try:
        return mesh_hidden(fit_mesh(arrays, fit.params, fit.vertices_f32), fit.keypoints_m, cameras)
    except ValueError as exc:  # a stored mesh or parameters this code cannot use: no flags, the proposals still go
        logger.warning("fit %s: %s; no occlusion flags", fit.id, exc)
        return None


def mesh_hidden(mesh: HandMesh, keypoints_m: Any, cameras: list[ViewCamera]) -> dict[str, list[bool]]:
    """View id -> (21,) whether the hand's mesh hides each keypoint (21, 3) metres, world frame, from that
    camera."""
    # deferred: the occlusion test and the skin tolerance load torch and cv2, kept out of the API's start-up
    from workers.rendering.occlusion import hidden_by_mesh
    from workers.synth.visibility import skin_depth_tolerance_m

    keypoints = np.asarray(keypoints_m, dtype=np.float64).reshape(21, 3)
    hidden = hidden_by_mesh(keypoints, mesh.vertices, mesh.faces, cameras,
                            skin_depth_tolerance_m(keypoints, mesh.vertices))
    return {str(cam.view_id): [bool(h) for h in hidden[c]] for c, cam in enumerate(cameras)}


def detector_proposal(fit: Fit, cameras: list[ViewCamera]) -> dict[str, Any] | None:
    """The pretrained detector's keypoints behind a pre-annotation fit (workers.tasks.preannotate), as a proposal
    source "detector": per view a keypoint's own detection where the view agreed with the triangulation (an
    inlier), else the triangulated keypoint projected into it; None for fits of any other source."""
    detection = (fit.inputs or {}).get("detection") if (fit.inputs or {}).get("source") == "detector" else None
    if not isinstance(detection, dict):
        return None
    try:
        view_ids = [int(v) for v in detection["view_ids"]]
        points = np.array(detection["points_world"], dtype=np.float64).reshape(21, 3)
        confidence = np.nan_to_num(np.array(detection["confidence"], dtype=np.float64).reshape(21), nan=0.0)
        inliers = np.asarray(detection["inliers"], dtype=bool).reshape(21, len(view_ids))
        views = list(detection["views"])
    except (KeyError, TypeError, ValueError) as exc:  # a stored record this code cannot read: no proposal
        logger.warning("fit %s: unreadable detection (%s); no detector proposals", fit.id, exc)
        return None
    projected = _projections(points, cameras)
    column = {view_id: c for c, view_id in enumerate(view_ids)}
    out: dict[str, list[list[float] | None]] = {}
    for cam in cameras:
        pixels = np.array(projected[cam.view_id], dtype=np.float64)
        c = column.get(cam.view_id)
        view = views[c] if c is not None and c < len(views) else None
        if view is not None:
            own = np.array(view.get("keypoints_px"), dtype=np.float64).reshape(21, 2)
            use = inliers[:, c] & np.isfinite(own).all(1)
            pixels[use] = own[use]
        out[str(cam.view_id)] = pixels_or_none(pixels)
    frame = detection.get("frame_confidence")
    label = f"detector (confidence {frame:.2f})" if isinstance(frame, int | float) else "detector"
    return {"kind": "detector", "label": label, "confidences": [round(float(c), 4) for c in confidence],
            "views": out}


def _residuals(fit_px: dict[int, np.ndarray], clicks: list[ClickRow]) -> dict[int, dict[int, float]]:
    """view id -> keypoint -> distance (pixels) between the fit's projection and the click."""
    out: dict[int, dict[int, float]] = {}
    for c in clicks:
        if c.x is None or c.y is None or c.view_id not in fit_px:
            continue
        p = fit_px[c.view_id][c.keypoint]
        if np.isfinite(p).all():
            out.setdefault(c.view_id, {})[c.keypoint] = round(float(np.hypot(p[0] - c.x, p[1] - c.y)), 2)
    return out


def residual_summary(residuals: dict[int, dict[int, float]], clicks: list[ClickRow]) -> dict[str, dict[str, Any]]:
    """The fit's distances to the points placed by hand ("clicked") apart from those accepted from proposals
    ("accepted"): a fit always lands near the proposal it came from, so mixing them flatters it. Each: count,
    mean and max (px; None without any)."""
    accepted = {(c.view_id, c.keypoint) for c in clicks if c.from_proposal}
    groups: dict[str, list[float]] = {"clicked": [], "accepted": []}
    for view_id, per_keypoint in residuals.items():
        for keypoint, value in per_keypoint.items():
            groups["accepted" if (view_id, keypoint) in accepted else "clicked"].append(value)
    return {name: {"n": len(values), "mean_px": round(float(np.mean(values)), 2) if values else None,
                   "max_px": round(float(np.max(values)), 2) if values else None} for name, values in groups.items()}


def _b64(array: np.ndarray, dtype: str) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode("ascii")


def _mesh_payload(fit: Fit, mano_path: Path | None) -> tuple[dict[str, Any] | None, str | None, float | None]:
    """(mesh, note, keypoint offset mm): the fit's mesh as little-endian float32 vertices (V, 3) and int32
    faces (F, 3), base64; or None and why not."""

    arrays = load_arrays(fit.model_file, mano_path, fit_side(fit.diagnostics))
    if arrays is None:
        return None, f"no mesh: the fit used {fit.model_file} and this server has no HANDLOOP_MANO_PATH", None
    try:
        mesh = fit_mesh(arrays, fit.params, fit.vertices_f32)
    except ValueError as exc:
        logger.warning("fit %s: %s; no mesh", fit.id, exc)
        return None, f"no mesh: {exc}", None
    # The keypoints regressed from the mesh should land on the stored ones.
    offset_mm = float(np.max(np.linalg.norm(mesh.keypoints - np.asarray(fit.keypoints_m), axis=1)) * 1000)
    if offset_mm > 1.0:
        logger.warning("fit %s: mesh keypoints are %.1f mm from the stored keypoints", fit.id, offset_mm)
    payload = {"num_vertices": len(mesh.vertices), "num_faces": len(mesh.faces),
               "vertices_f32": _b64(mesh.vertices, "<f4"), "faces_i32": _b64(mesh.faces, "<i4")}
    return payload, None, round(offset_mm, 3)


def review_overlay(session: Session, user: Actor, sample_id: int, *, secret_key: str, mano_path: Path | None = None,
                   with_mesh: bool = True) -> dict[str, Any]:
    """Everything the review page draws for a sample under the caller's review lease."""

    sample = _held(session, user, sample_id, LeaseKind.review)
    if sample.current_fit_id is None:
        raise ConflictError(f"sample {sample_id} has no fit to review")
    fit = session.get(Fit, sample.current_fit_id, options=[undefer(Fit.vertices_f32)])
    if fit is None:
        raise NotFoundError(f"fit {sample.current_fit_id} of sample {sample_id} not found")
    cameras = view_cameras(session, sample_id)
    submission_ids = (fit.inputs or {}).get("submission_ids") or None
    clicks = clicks_of(session, sample_id, submission_ids) if submission_ids else []
    prediction = session.get(Prediction, fit.prediction_id) if fit.prediction_id else None
    end_reads(session)
    fit_px = _projections(fit.keypoints_m, cameras)
    pred_px = _projections(prediction.keypoints_m, cameras) if prediction is not None else {}
    residuals = _residuals(fit_px, clicks)
    detections = fitted_detections(fit.inputs, cameras) if not clicks else None
    if detections is not None:  # fitted from the detector's keypoints: measure against those it used
        residuals = _residuals(fit_px, [ClickRow(view_id, k, x, y, "visible") for view_id, points in detections.items()
                                        for k, (x, y) in points.items()])
    elif not clicks and prediction is not None:  # fitted from MVNet: measure against its keypoints instead
        residuals = {v: {k: round(float(np.hypot(*(fit_px[v][k] - pred_px[v][k]))), 2) for k in SPARSE_KEYPOINTS
                         if np.isfinite(fit_px[v][k]).all() and np.isfinite(pred_px[v][k]).all()}
                     for v in fit_px}
    ious = {int(k): float(v) for k, v in (fit.view_ious or {}).items()}
    views = []
    for cam in cameras:
        res = residuals.get(cam.view_id, {})
        views.append({
            **cam.to_public(),
            "iou": round(ious[cam.view_id], 4) if cam.view_id in ious else None,
            "fit_keypoints_px": pixels_or_none(fit_px[cam.view_id]),
            "prediction_keypoints_px": pixels_or_none(pred_px[cam.view_id]) if pred_px else None,
            "residual_px": {str(k): v for k, v in sorted(res.items())},
            "mean_residual_px": round(float(np.mean(list(res.values()))), 2) if res else None,
            "clicks": [c.to_public() for c in clicks if c.view_id == cam.view_id],
        })
    all_res = [v for r in residuals.values() for v in r.values()]
    by_origin = residual_summary(residuals, clicks) if clicks else None
    mesh, mesh_note, offset_mm = _mesh_payload(fit, mano_path) if with_mesh else (None, "not requested", None)
    ticket = scene_tickets.issue(secret_key, user.id, sample_id, fit.id, token_version=user.token_version)
    keypoints = np.asarray(fit.keypoints_m, dtype=np.float64)
    return {
        "sample_id": sample_id,
        "fit_id": fit.id,
        "hand_model": {"model_file": fit.model_file, "stand_in": is_stand_in(fit.model_file),
                       "label": hand_model_label(fit.model_file), "side": fit_side(fit.diagnostics)},
        "fit": {"keypoints_m": keypoints.round(6).tolist(), "source": "annotations" if submission_ids else
                DETECTOR_SOURCE if (fit.inputs or {}).get("source") == DETECTOR_SOURCE else "prediction",
                "heuristic": None,  # blind: an audited heuristic accept would show 'passed' (review.label_audits)
                "pose_distance": round(float(fit.pose_distance), 4),
                "mean_iou": round(float(np.mean(list(ious.values()))), 4) if ious else None,
                "mean_residual_px": round(float(np.mean(all_res)), 2) if all_res else None,
                "max_residual_px": round(float(np.max(all_res)), 2) if all_res else None,
                "residual_reference": "clicks" if clicks else DETECTOR_SOURCE if detections is not None
                else "mvnet" if prediction is not None else None,
                "residual_by_origin": by_origin,
                "mesh_keypoint_offset_mm": offset_mm, "created_at": fit.created_at.isoformat()},
        "prediction": None if prediction is None else {
            "mvnet_version": prediction.mvnet_version, "mean_confidence": round(float(prediction.mean_confidence), 4),
            "confidences": [round(float(c), 4) for c in prediction.confidences]},
        "views": views,
        "mesh": mesh,
        "mesh_note": mesh_note,
        "skeleton_edges": [list(e) for e in SKELETON_EDGES],
        "scene_path": f"/api/viewer/samples/{sample_id}/scene?ticket={ticket}",
        **_scene_view(keypoints, cameras),
    }


def _scene_view(keypoints: np.ndarray, cameras: list[ViewCamera]) -> dict[str, list[float]]:
    """Where the page's 3D view starts (backend.viewer.scene.viewpoint: the rig's own up, the cameras' side)."""
    view = viewpoint(keypoints, [c.R for c in cameras], [c.t for c in cameras])
    return {"scene_look_at": list(view.look_at), "scene_eye": list(view.eye), "scene_up": list(view.up)}
