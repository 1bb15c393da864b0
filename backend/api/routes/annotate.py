from __future__ import annotations

from fastapi import APIRouter, Response

from backend.api.deps import AnnotatorUser, JobQueueDep, SessionDep, SettingsDep, StorageDep, commit_in_route
from backend.api.routes.tasks_common import json_response, task_of
from backend.models.enums import LeaseKind
from backend.schemas.base import Id
from backend.schemas.drafts import AnnotateDraftIn, DraftPublic
from backend.schemas.tasks import LeasePublic, LeaseRequest, SubmissionCreate, SubmissionPublic, TaskPublic
from backend.services import drafts, queues, submissions

router = APIRouter(prefix="/annotate", tags=["annotator queue"])


@router.post("/next", response_model=TaskPublic, responses={204: {"description": "The queue is empty."}})
def next_task(session: SessionDep, settings: SettingsDep, user: AnnotatorUser) -> Response:
    """Lease the next sample needing annotation (or return the one you already hold, renewed)."""
    lease = queues.acquire(session, user, LeaseKind.annotate, settings.lease_seconds, sole_statement=True)
    if lease is None:
        return Response(status_code=204)
    task = task_of(session, lease)  # PostgreSQL: built from the lease statement's rows alone
    commit_in_route(session)
    return json_response(task)


@router.post("/samples/{sample_id}/lease/renew", response_model=LeasePublic)
def renew(sample_id: Id, body: LeaseRequest, session: SessionDep, settings: SettingsDep,
          user: AnnotatorUser) -> LeasePublic:
    lease = queues.renew(session, user, sample_id, LeaseKind.annotate, body.lease_token, settings.lease_seconds)
    return LeasePublic(sample_id=lease.sample_id, lease_token=lease.token, lease_expires_at=lease.expires_at)


@router.post("/samples/{sample_id}/lease/release", status_code=204)
def release(sample_id: Id, body: LeaseRequest, session: SessionDep, user: AnnotatorUser) -> None:
    queues.release(session, user, sample_id, LeaseKind.annotate, body.lease_token)


@router.post("/samples/{sample_id}/submissions", response_model=SubmissionPublic, status_code=201,
             responses={200: {"description": "Already submitted with this submission_id: nothing new written."}})
def submit(sample_id: Id, body: SubmissionCreate, session: SessionDep, settings: SettingsDep,
           queue: JobQueueDep, storage: StorageDep, user: AnnotatorUser) -> Response:
    """Clicks and mask corrections for a leased sample; queues a fit. Idempotent on `submission_id`."""
    result = submissions.submit(session, queue, storage, user, sample_id, body, settings.max_clicks_per_submission)
    commit_in_route(session)
    s = result.submission
    public = SubmissionPublic.model_construct(
        id=s.id, submission_id=s.client_id, sample_id=s.sample_id, n_clicks=s.n_clicks, n_masks=s.n_masks,
        fit_job_id=s.fit_job_id, duplicate=result.duplicate, created_at=s.created_at)
    return json_response(public, status_code=200 if result.duplicate else 201)


@router.post("/samples/{sample_id}/lease/retake", response_model=LeasePublic)
def retake(sample_id: Id, body: LeaseRequest, session: SessionDep, settings: SettingsDep,
           user: AnnotatorUser) -> LeasePublic:
    """Take a lapsed lease again while nobody else holds the sample (409 naming why otherwise)."""
    lease = queues.retake(session, user, sample_id, LeaseKind.annotate, body.lease_token, settings.lease_seconds)
    return LeasePublic(sample_id=lease.sample_id, lease_token=lease.token, lease_expires_at=lease.expires_at)


@router.get("/samples/{sample_id}/draft", response_model=DraftPublic,
            responses={204: {"description": "No draft of yours for this sample."}})
def get_draft(sample_id: Id, session: SessionDep, user: AnnotatorUser) -> Response:
    """Your clicks and masks in progress on a sample whose lease you hold."""
    draft = drafts.get(session, user, sample_id, LeaseKind.annotate)
    return Response(status_code=204) if draft is None else json_response(DraftPublic(**drafts.public(draft)))


@router.put("/samples/{sample_id}/draft", response_model=DraftPublic)
def save_draft(sample_id: Id, body: AnnotateDraftIn, session: SessionDep, settings: SettingsDep,
               user: AnnotatorUser) -> Response:
    """Save your clicks and masks in progress (replacing the previous save); deleted when you submit."""
    draft = drafts.save(session, user, sample_id, LeaseKind.annotate, body, settings.max_upload_bytes)
    return json_response(DraftPublic(**drafts.public(draft)))


@router.delete("/samples/{sample_id}/draft", status_code=204)
def discard_draft(sample_id: Id, session: SessionDep, user: AnnotatorUser) -> None:
    """Throw your draft of a sample away."""
    drafts.discard(session, user, sample_id, LeaseKind.annotate)
