from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter

from backend.api.deps import AdminUser, SessionDep, StorageDep
from backend.schemas.admin import ImportPublic, ImportRequest
from backend.services import importer

router = APIRouter(prefix="/admin/imports", tags=["admin: import"])


@router.post("", response_model=ImportPublic, status_code=201)
def import_capture(body: ImportRequest, session: SessionDep, storage: StorageDep, admin: AdminUser) -> ImportPublic:
    """Import a capture directory that the server can read (validated by the capture reader)."""
    return importer.import_capture(session, storage, Path(body.path), project_name=body.project,
                                   queue_for_annotation=body.queue_for_annotation, actor_id=admin.id)
