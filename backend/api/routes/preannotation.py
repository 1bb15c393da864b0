"""Pre-annotation (issue 15, round 0 without clicks): whether the detector can run, and launching it."""

from __future__ import annotations

from fastapi import APIRouter

from backend.api.deps import AdminUser, JobQueueDep, SessionDep
from backend.schemas.admin import PreannotateLaunched, PreannotateRequest, PreannotationOverview
from backend.services.rounds import preannotation

router = APIRouter(prefix="/admin/preannotation", tags=["admin: pre-annotation"])


@router.get("", response_model=PreannotationOverview)
def overview(session: SessionDep, _admin: AdminUser) -> dict[str, object]:
    """Whether the pretrained hand detector's model files are installed and verified; the projects it could run on."""
    return preannotation.overview(session)


@router.post("", response_model=PreannotateLaunched, status_code=202)
def launch(body: PreannotateRequest, session: SessionDep, queue: JobQueueDep, admin: AdminUser) -> PreannotateLaunched:
    """Queue the project's pre-annotation job; refused (503, with the detector's sentence) where it cannot run."""
    job = preannotation.launch(session, queue, body.project_id, actor_id=admin.id, sample_ids=body.sample_ids,
                               rest=body.rest, handedness=body.handedness)
    return PreannotateLaunched(job_id=job.id, project_id=body.project_id, samples=len(job.payload["sample_ids"]))
