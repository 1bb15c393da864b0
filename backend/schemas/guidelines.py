"""The labelling guidelines: what every page shows, and the admin's edits."""

from __future__ import annotations

from datetime import datetime

from pydantic import Field

from backend.schemas.base import Public, Strict


class GuidelineImage(Public):
    id: str = Field(description="Fetch it at /api/guidelines/images/{id} (signed in).")
    caption: str
    content_type: str


class GuidelinesPublic(Public):
    text: str = Field(description="Plain text; blank lines separate paragraphs.")
    images: list[GuidelineImage]
    revision: int = Field(description="Saves so far (0: never saved); send it back with an edit.")
    updated_at: datetime | None
    updated_by_id: int | None


class GuidelinesText(Strict):
    text: str = Field(max_length=50_000)
    revision: int = Field(ge=0, le=2**31 - 1, description="The revision the edit was made on.")
