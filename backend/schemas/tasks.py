"""Annotator and reviewer queues: tasks, submissions, decisions."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from backend.models.enums import DecisionKind, SampleState, Visibility
from backend.schemas.base import Finite, Id, Pixel, Public, Strict, enum_from_json, whole

ClientId = Annotated[str, Field(min_length=8, max_length=64, pattern=r"^[A-Za-z0-9_.:-]+$")]
LeaseToken = Annotated[str, Field(min_length=1, max_length=64)]


class ViewPublic(Public):
    id: int
    camera: str
    width: int
    height: int
    image_url: str
    mask_url: str | None


class TaskPublic(Public):
    sample_id: int
    state: SampleState
    lease_token: str
    lease_expires_at: datetime
    sequence_id: int
    sequence: str | None = Field(default=None, description="The sequence's name in the capture and exports.")
    side: Literal["right", "left"] = Field(default="right", description="Which hand the sequence shows.")
    frame_index: int
    time_s: float
    keypoints_to_click: list[int]
    views: list[ViewPublic]
    fit: dict[str, Any] | None = None


class LeasePublic(Public):
    sample_id: int
    lease_token: str
    lease_expires_at: datetime


class LeaseRequest(Strict):
    lease_token: LeaseToken | None = None


class ClickIn(Strict):
    # The cross-field rule below, in the published schema too (clients and fuzzers see what is refused).
    model_config = ConfigDict(json_schema_extra={
        "if": {"properties": {"visibility": {"const": "not_annotated"}}, "required": ["visibility"]},
        "then": {"properties": {"x": {"type": "null"}, "y": {"type": "null"}}},
        "else": {"required": ["x", "y"], "properties": {"x": {"type": "number"}, "y": {"type": "number"}}}})

    view_id: Id
    keypoint: int = Field(ge=0, le=20)
    x: Pixel | None = None
    y: Pixel | None = None
    visibility: Visibility = Visibility.visible
    from_proposal: bool = Field(default=False, description="Accepted from a proposal (triangulated, fit, MVNet), "
                                "not placed by hand: weighed as a proposal, not as a click.")

    # Strict's conversions for the three fields that need them, not for all six: a submission holds ~50 clicks,
    # and a Python call per field of each was most of its validation (same results, same messages).
    @field_validator("view_id", "keypoint", mode="before")
    @classmethod
    def _from_json_values(cls, value: Any) -> Any:  # the name shadows Strict's validator of every field
        return whole(value)

    @field_validator("visibility", mode="before")
    @classmethod
    def _visibility_from_json(cls, value: Any) -> Any:
        return enum_from_json(Visibility, value)

    @model_validator(mode="after")
    def _position_matches_visibility(self) -> ClickIn:
        has_xy = self.x is not None and self.y is not None
        if self.visibility is Visibility.not_annotated:
            if self.x is not None or self.y is not None:
                raise ValueError("a keypoint that is not annotated has no x, y")
        elif not has_xy:
            raise ValueError(f"a {self.visibility.value} keypoint needs both x and y")
        return self


class MaskIn(Strict):
    """A corrected mask, row-major run lengths starting with a run of background (0) pixels."""

    view_id: Id
    width: int = Field(ge=1, le=100_000)
    height: int = Field(ge=1, le=100_000)
    rle: list[Annotated[int, Field(ge=0, le=10**10)]] = Field(min_length=1, max_length=4_000_000)


class SubmissionCreate(Strict):
    # The validator's rule in the published schema too: a corrected mask, or a click that is not 'not_annotated'.
    model_config = ConfigDict(json_schema_extra={"anyOf": [
        {"required": ["clicks"], "properties": {"clicks": {"minItems": 1, "contains": {
            "not": {"required": ["visibility"], "properties": {"visibility": {"const": "not_annotated"}}}}}}},
        {"required": ["masks"], "properties": {"masks": {"minItems": 1}}}]})

    submission_id: ClientId = Field(description="Client-chosen unique id: resubmitting it is a no-op.")
    lease_token: LeaseToken | None = None
    time_spent_s: Finite = Field(ge=0, le=24 * 3600)
    clicks: list[ClickIn] = Field(default_factory=list, max_length=100_000)
    masks: list[MaskIn] = Field(default_factory=list, max_length=64)
    no_hand_views: list[Id] = Field(default_factory=list, max_length=64, description=(
        "Views the annotator marked 'no hand here': their clicks must all be not annotated; stored and counted, "
        "kept out of the fit. A sample with no hand in any view is marked with POST .../skip (kind 'no_hand')."))

    @model_validator(mode="after")
    def _not_empty(self) -> SubmissionCreate:
        if not self.clicks and not self.masks:
            raise ValueError("a submission needs clicks or masks")
        if not self.masks and all(c.visibility is Visibility.not_annotated for c in self.clicks):
            # Nothing for the fit to fit: it would fail and send the sample straight back (issue 38).
            raise ValueError("every keypoint is 'not_annotated' and no mask is corrected: nothing to fit; place "
                             "points, or mark the sample 'no hand' or skip it (POST .../skip)")
        return self


class SubmissionPublic(Public):
    id: int
    submission_id: str
    sample_id: int
    n_clicks: int
    n_masks: int
    fit_job_id: int | None
    duplicate: bool
    created_at: datetime


class SkipCreate(Strict):
    """An annotator passing on a leased sample instead of clicking it, with the reason."""

    kind: Literal["skip", "no_hand"] = Field(description="'skip': back to the queue, for someone else; 'no_hand': "
                                             "no hand in any view, out of the queue as rejected.")
    reason: str = Field(min_length=1, max_length=500)
    lease_token: LeaseToken | None = None

    @field_validator("reason")
    @classmethod
    def _reason_not_blank(cls, value: str) -> str:
        if not value.strip():
            raise ValueError("a skip or 'no hand' needs a reason")
        return value.strip()


class SkipPublic(Public):
    sample_id: int
    kind: str
    state: SampleState


class FitFailurePublic(Public):
    sample_id: int
    submission_id: int | None
    reason: str
    at: datetime


NEEDS_REASON = frozenset({DecisionKind.reject, DecisionKind.annotate})


class DecisionCreate(Strict):
    model_config = ConfigDict(json_schema_extra={
        "if": {"properties": {"decision": {"enum": ["reject", "annotate"]}}},
        "then": {"required": ["reason"], "properties": {"reason": {"pattern": "\\S"}}}})

    decision: DecisionKind = Field(description="'accept'; 'reject' (final); 'annotate' (to the annotators); 'discard' "
                                               "(a fit from predictions only: the sample waits for the next round's "
                                               "networks; on a blind audit, as 'annotate').")
    reason: str = Field(default="", max_length=2000)
    lease_token: LeaseToken | None = None

    @model_validator(mode="after")
    def _reason_when_sending_on(self) -> DecisionCreate:
        # A discard is the quick "not good enough" (the paper's ~5 s look): its reason is optional.
        if self.decision in NEEDS_REASON and not self.reason.strip():
            raise ValueError(f"a '{self.decision.value}' decision needs a reason")
        return self


class DecisionPublic(Public):
    id: int
    sample_id: int
    fit_id: int | None
    decision: DecisionKind
    reason: str
    state: SampleState = Field(description="The sample's state after the decision (for a gold answer: unchanged).")
    stream: str | None = Field(description="The dataset stream the label joined with this decision; null when "
                                           "nothing joined (a reject, a send-back, a discard, a gold answer).")
    created_at: datetime
    recorded_as: Literal["review", "gold_answer"] = Field(
        default="review",
        description="'review': the decision moved the sample as `state` says. 'gold_answer': the sample is a gold "
                    "label (known right), a test of the reviewer: the decision is recorded as their answer to it "
                    "(agreement with gold, per person) and the sample's state and label are unchanged.")
