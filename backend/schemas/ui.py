"""Requests and responses of the routes the browser UI adds: prefetch, proposals, review overlays, the
3D scene, activity logs, the admin dashboard."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field

from backend.schemas.base import Finite, Id, Public, Strict
from backend.schemas.tasks import ClientId

Pixel2 = Annotated[list[float], Field(min_length=2, max_length=2)]
DAY_MS = 24 * 3600 * 1000


class PrefetchRequest(Strict):
    current_sample_id: Id = Field(description="The sample on screen: the prefetched one is another.")


class CameraPublic(Public):
    view_id: int
    camera: str
    width: int
    height: int
    K: list[list[float]]
    dist: list[float]
    R: list[list[float]]
    t: list[float]


class ClickPublic(Public):
    view_id: int
    keypoint: int
    x: float | None
    y: float | None
    visibility: str
    from_proposal: bool = Field(default=False, description="Accepted from a proposal, not placed by hand.")


class ProposalSource(Public):
    kind: Literal["detector", "mvnet", "fit"]
    label: str
    confidences: list[float | None] | None = Field(
        description="Per keypoint (21): MVNet's, the detector's lifted ones, or a fit's agreement with what it was "
        "fitted to (the detector's keypoints or the hand-placed clicks; null where nothing observed the keypoint).")
    views: dict[str, list[Pixel2 | None]] = Field(description="View id -> 21 projected keypoints (px) or null.")
    hidden: dict[str, list[bool]] | None = Field(
        default=None, description="The fit's only: view id -> 21 flags, true where the fit's mesh hides the keypoint "
                                  "from that camera (accepted as occluded); null for other sources or without a mesh.")


class FitFailureNote(Public):
    reason: str
    at: datetime


class ProposalsPublic(Public):
    sample_id: int
    cameras: list[CameraPublic]
    keypoints_to_click: list[int]
    sources: list[ProposalSource]
    previous_clicks: list[ClickPublic]
    review_note: str | None
    fit_failure: FitFailureNote | None = Field(
        default=None, description="Why the sample's newest fit failed, when it did and no fit was made since.")


class HandModelPublic(Public):
    model_file: str
    stand_in: bool
    label: str = Field(description="'built-in stand-in hand, not MANO' when the stand-in made the fit.")


class ReviewView(CameraPublic):
    iou: float | None
    fit_keypoints_px: list[Pixel2 | None]
    prediction_keypoints_px: list[Pixel2 | None] | None
    residual_px: dict[str, float] = Field(description="Keypoint -> distance (px) of the fit to the reference.")
    mean_residual_px: float | None
    clicks: list[ClickPublic]


class MeshPublic(Public):
    num_vertices: int
    num_faces: int
    vertices_f32: str = Field(description="base64 of little-endian float32 (V, 3), metres, world frame.")
    faces_i32: str = Field(description="base64 of little-endian int32 (F, 3).")


class ReviewOverlayPublic(Public):
    sample_id: int
    fit_id: int
    hand_model: HandModelPublic
    fit: dict[str, Any]
    prediction: dict[str, Any] | None
    views: list[ReviewView]
    mesh: MeshPublic | None
    mesh_note: str | None
    skeleton_edges: list[list[int]]
    scene_path: str = Field(description="The 3D scene of this sample for viser's client (?playbackPath=).")
    scene_look_at: list[float] = Field(description="The hand's centre: where the 3D view looks (world, metres).")
    scene_eye: list[float] = Field(description="Where the 3D view starts (world, metres), on the cameras' side.")
    scene_up: list[float] = Field(description="The rig's up (unit vector): a real rig's world is often y-down.")


class ActionIn(Strict):
    # Every kind the annotate and review pages mark (frontend/js/*.js `timer.mark`): a log the page sends is
    # never refused for a kind the page itself uses ("reason": a common review reason picked with 1-5).
    kind: Literal["click", "accept", "drag", "occlude", "not_annotated", "brush", "erase", "undo", "redo", "view",
                  "zoom", "toggle", "reason", "decide"]
    at_ms: Finite = Field(ge=0, le=DAY_MS, description="Since the task was shown.")
    duration_ms: Finite = Field(ge=0, le=DAY_MS, description="Since the previous action (idle time capped).")
    view_id: Id | None = None
    keypoint: int | None = Field(default=None, ge=0, le=20)
    reprojected: int | None = Field(default=None, ge=0, le=21 * 64, description=(
        "Accepted proposals in other views that this placed point moved with it (triangulated again)."))


class ActivityCreate(Strict):
    # services.statistics.activity's rule (a log belongs to a submission or a decision), in the published schema too.
    model_config = ConfigDict(json_schema_extra={"allOf": [
        {"if": {"properties": {"context": {"const": "annotate"}}},
         "then": {"required": ["submission_id"], "properties": {"submission_id": {"type": "string"}}}},
        {"if": {"properties": {"context": {"const": "review"}}},
         "then": {"required": ["decision_id"], "properties": {"decision_id": {"type": "integer"}}}}]})

    context: Literal["annotate", "review"]
    sample_id: Id
    submission_id: ClientId | None = None
    decision_id: Id | None = None
    time_spent_s: Finite = Field(ge=0, le=24 * 3600)
    actions: list[ActionIn] = Field(default_factory=list, max_length=20_000)


class ActivityPublic(Public):
    id: int
    duplicate: bool
    summary: dict[str, Any]


class DashboardPublic(Public):
    queues: dict[str, int] = Field(description="Free samples per queue ('annotate', 'review') and those leased "
                                   "now ('annotate_leased', 'review_leased').")
    launch: dict[str, Any] = Field(description="accepted labels, the minimum a round trains on, and the refusal "
                                   "in plain words (null: a round can be launched).")
    fits: int
    fits_by_hand_model: dict[str, int] = Field(description="Label -> fits; the stand-in is 'built-in stand-in hand, "
                                               "not MANO'.")
    confidence_histogram: dict[str, Any]
    sparsification: dict[str, Any] | None
    human_time: dict[str, Any]
    flags: dict[str, int] = Field(default_factory=dict, description="Annotation flags by kind: 'no_hand_view', "
                                  "'no_hand', 'skip', 'fit_failed' (issue 38).")
