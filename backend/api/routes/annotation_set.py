"""Admin: which samples people annotate (e.g. the initial set D_0)."""

from __future__ import annotations

from fastapi import APIRouter

from backend.api.deps import AdminUser, SessionDep
from backend.schemas.annotation_set import AnnotationSetQueued, AnnotationSetRequest
from backend.services.labeling.annotation_set import queue_for_annotation

router = APIRouter(prefix="/admin/samples", tags=["admin: samples"])


@router.post("/queue-for-annotation", response_model=AnnotationSetQueued)
def queue(body: AnnotationSetRequest, session: SessionDep, admin: AdminUser) -> AnnotationSetQueued:
    """Move unlabeled samples to the annotator queue (all or nothing: 409 naming any in another state)."""
    return AnnotationSetQueued(queued=queue_for_annotation(session, body.sample_ids, admin.id))
