"""Admin exports of the server's records: the accepted dataset, the sample index, MVNet's predictions.
The FreiHAND-layout files are written by a worker's export job (it needs the hand model and torch, which the
API process does not load), queued here and downloaded as one zip once it succeeded, or by
`handloop export --format freihand` from the same records."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Query
from fastapi.responses import FileResponse, Response

from backend.api.deps import AdminUser, JobQueueDep, SessionDep, StorageDep
from backend.schemas.base import Id
from backend.schemas.exports import ExportQueued, FreihandExportCreate
from backend.services.captures.storage import LocalDiskStorage
from backend.services.exports import export, export_jobs

router = APIRouter(prefix="/admin/exports", tags=["admin: exports"])
# A project's name as a query parameter: PostgreSQL text cannot hold NUL, so it is a 422 here, not at the query.
ProjectQuery = Query(default=None, min_length=1, max_length=200, pattern=r"^[^\x00]*$")


@router.get("/dataset")
def export_dataset(session: SessionDep, _admin: AdminUser,
                   up_to_round: int | None = Query(default=None, ge=0, le=1_000_000),
                   project: str | None = ProjectQuery) -> dict[str, Any]:
    """The accepted samples (D_i up to a round index) with their fits, rounds and streams, and the hand
    models that made the labels."""
    return export.dataset(session, up_to_round, project)


@router.get("/samples")
def export_samples(session: SessionDep, _admin: AdminUser,
                   project: str | None = ProjectQuery) -> dict[str, Any]:
    """Every sample: id, sequence (external id), frame, split, state, current fit."""
    return export.sample_index(session, project)


@router.get("/predictions")
def export_predictions(session: SessionDep, _admin: AdminUser,
                       round_index: int | None = Query(default=None, ge=0, le=1_000_000)) -> dict[str, Any]:
    """MVNet's predictions with their round, keypoints (world frame, metres) and confidences."""
    return export.predictions(session, round_index)


@router.post("/freihand", response_model=ExportQueued, status_code=202, responses={404: {}, 409: {}})
def export_freihand(body: FreihandExportCreate, session: SessionDep, queue: JobQueueDep,
                    admin: AdminUser) -> ExportQueued:
    """Queue an export job writing the accepted samples in FreiHAND's layout (as `handloop export --format
    freihand`), zipped; follow it at /api/admin/jobs/{id}/events and download it from .../archive. 409 when
    no sample is accepted yet."""
    job = export_jobs.queue_freihand_export(session, queue, admin.id, up_to_round=body.up_to_round,
                                            project=body.project, composites=body.composites, meshes=body.meshes)
    return ExportQueued(job_id=job.id, samples=int(job.payload["samples"]))


@router.get("/freihand/{job_id}/archive", response_class=Response, responses={404: {}, 409: {}})
def export_freihand_archive(job_id: Id, session: SessionDep, storage: StorageDep, _admin: AdminUser) -> Response:
    """The zip an export job wrote (404 for no such export job, 409 while it runs or when it failed)."""
    key = export_jobs.finished_archive(session, job_id)
    filename = f"handloop-freihand-job-{job_id}.zip"
    if isinstance(storage, LocalDiskStorage):
        path = storage.local_path(key)
        if path.is_file():
            return FileResponse(path, media_type="application/zip", filename=filename)
    return Response(storage.get_bytes(key), media_type="application/zip",
                    headers={"Content-Disposition": f'attachment; filename="{filename}"'})
