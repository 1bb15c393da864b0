from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter

from backend.api.deps import AdminUser, JobQueueDep, SessionDep, SettingsDep, StorageDep
from backend.schemas.admin import ImportPublic, ImportRequest
from backend.services.captures import importer
from backend.services.rounds import preannotation

router = APIRouter(prefix="/admin/imports", tags=["admin: import"])


@router.post("", response_model=ImportPublic, status_code=201)
def import_capture(body: ImportRequest, session: SessionDep, storage: StorageDep, settings: SettingsDep,
                   queue: JobQueueDep, admin: AdminUser) -> ImportPublic:
    """Import a capture folder inside one of the server's import roots (HANDLOOP_IMPORT_ROOTS, else
    <data_dir>/captures; 422 naming them otherwise, and for a file linked to outside the capture) validated by
    the capture reader; with
    `preannotate` (left out: HANDLOOP_PREANNOTATE_ON_IMPORT), then queue its samples' pre-annotation
    (services.rounds.preannotation): the job's progress is `GET /api/admin/jobs/{preannotation_job_id}/events`."""
    asked = body.preannotate is not None
    path = importer.check_import_path(Path(body.path), settings.allowed_import_roots)
    return preannotation.import_capture(session, storage, queue, path,
                                        enabled=body.preannotate if asked else settings.preannotate_on_import,
                                        required=bool(body.preannotate), project_name=body.project,
                                        queue_for_annotation=body.queue_for_annotation, actor_id=admin.id)
