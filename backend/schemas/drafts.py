"""Drafts: what an annotator or reviewer has done on a leased sample so far, saved as they work."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import Field

from backend.models.enums import DecisionKind
from backend.schemas.base import Finite, Id, Public, Strict
from backend.schemas.tasks import ClickIn, ClientId, LeaseToken, MaskIn

MAX_DRAFT_VIEWS = 64
BASE_REVISION = Field(default=None, ge=0, le=2**31 - 1, description=(
    "The draft revision this state was made on (0: no draft yet). A save whose base is not the stored revision, "
    "while the stored one came from another page (`writer`), is refused with 409 and writes nothing: two tabs or "
    "windows on one sample never overwrite each other silently. Left out: not checked."))
WRITER = Field(default=None, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_-]+$", description=(
    "Which page (a tab's editor) saves: its own later saves never conflict with each other."))
MAX_DRAFT_CLICKS = 21 * MAX_DRAFT_VIEWS


class AnnotateDraftIn(Strict):
    """The annotate page's state: clicks set so far (a click not yet made is simply absent), the masks
    corrected so far, where the annotator was, and the submission id the page will submit under (so a
    submit retried after a reload is still idempotent)."""

    lease_token: LeaseToken
    submission_id: ClientId
    time_spent_s: Finite = Field(ge=0, le=24 * 3600)
    clicks: list[ClickIn] = Field(default_factory=list, max_length=MAX_DRAFT_CLICKS)
    masks: list[MaskIn] = Field(default_factory=list, max_length=MAX_DRAFT_VIEWS)
    view_index: int = Field(default=0, ge=0, lt=MAX_DRAFT_VIEWS)
    keypoint: int = Field(default=0, ge=0, le=20)
    no_hand_views: list[Id] = Field(default_factory=list, max_length=MAX_DRAFT_VIEWS,
                                    description="Views marked 'no hand here' so far.")
    base_revision: int | None = BASE_REVISION
    writer: str | None = WRITER


class ReviewDraftIn(Strict):
    """The review page's note in progress: the decision picked (None: none yet) and the reason typed."""

    lease_token: LeaseToken
    decision: DecisionKind | None = None
    reason: str = Field(default="", max_length=2000)
    time_spent_s: Finite = Field(default=0.0, ge=0, le=24 * 3600)
    base_revision: int | None = BASE_REVISION
    writer: str | None = WRITER


class DraftPublic(Public):
    sample_id: int
    kind: str
    revision: int = Field(description="Saves so far: 1 after the first (the draft's version; see base_revision).")
    lease_token: str = Field(description="The lease it was saved under.")
    updated_at: datetime
    payload: dict[str, Any] = Field(description="The saved request body, less its lease token and base revision.")
    left_by: str | None = Field(default=None, description=(
        "Who left this work on the sample on a lease that lapsed (it travels with the sample to its next holder); "
        "null: the draft is the caller's own."))
