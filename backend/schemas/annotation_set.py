"""Admin: queueing chosen samples for annotation."""

from __future__ import annotations

from pydantic import Field

from backend.schemas.base import Id, Public, Strict


class AnnotationSetRequest(Strict):
    sample_ids: list[Id] = Field(min_length=1, max_length=100_000, description="Unlabeled samples to annotate.")


class AnnotationSetQueued(Public):
    queued: list[int]
