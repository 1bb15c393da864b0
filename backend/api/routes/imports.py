from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter

from backend.api.deps import AdminUser, JobQueueDep, SessionDep, SettingsDep, StorageDep
from backend.schemas.admin import ImportPublic, ImportRequest
from backend.services import preannotation

router = APIRouter(prefix="/admin/imports", tags=["admin: import"])


@router.post("", response_model=ImportPublic, status_code=201)
def import_capture(body: ImportRequest, session: SessionDep, storage: StorageDep, settings: SettingsDep,
                   queue: JobQueueDep, admin: AdminUser) -> ImportPublic:
    """Import a capture directory that the server can read (validated by the capture reader); with
    HANDLOOP_PREANNOTATE_ON_IMPORT, then pre-annotate its samples (services.preannotation)."""
    return preannotation.import_capture(session, storage, queue, Path(body.path),
                                        enabled=settings.preannotate_on_import, project_name=body.project,
                                        queue_for_annotation=body.queue_for_annotation, actor_id=admin.id)
