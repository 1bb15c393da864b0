from __future__ import annotations

from fastapi import APIRouter, Response

from backend.api.deps import ReviewerUser, SessionDep, SettingsDep
from backend.api.routes.tasks_common import json_response, task_of
from backend.models.enums import LeaseKind
from backend.schemas.base import Id
from backend.schemas.drafts import DraftPublic, ReviewDraftIn
from backend.schemas.tasks import DecisionCreate, DecisionPublic, LeasePublic, LeaseRequest, TaskPublic
from backend.services import drafts, queues, review

router = APIRouter(prefix="/review", tags=["reviewer queue"])


@router.post("/next", response_model=TaskPublic, responses={204: {"description": "The queue is empty."}})
def next_task(session: SessionDep, settings: SettingsDep, user: ReviewerUser) -> TaskPublic | Response:
    """Lease the most confident sample awaiting verification, with its fit."""
    lease = queues.acquire(session, user, LeaseKind.review, settings.lease_seconds)
    if lease is None:
        return Response(status_code=204)
    return task_of(session, lease, with_fit=True)


@router.post("/samples/{sample_id}/lease/renew", response_model=LeasePublic)
def renew(sample_id: Id, body: LeaseRequest, session: SessionDep, settings: SettingsDep,
          user: ReviewerUser) -> LeasePublic:
    lease = queues.renew(session, user, sample_id, LeaseKind.review, body.lease_token, settings.lease_seconds)
    return LeasePublic(sample_id=lease.sample_id, lease_token=lease.token, lease_expires_at=lease.expires_at)


@router.post("/samples/{sample_id}/lease/release", status_code=204)
def release(sample_id: Id, body: LeaseRequest, session: SessionDep, user: ReviewerUser) -> None:
    queues.release(session, user, sample_id, LeaseKind.review, body.lease_token)


@router.post("/samples/{sample_id}/decision", response_model=DecisionPublic, status_code=201)
def decide(sample_id: Id, body: DecisionCreate, session: SessionDep, user: ReviewerUser) -> DecisionPublic:
    """Accept, reject, or send back for annotation (with a reason) a sample whose review lease you hold."""
    row, sample, stream = review.decide(session, user, sample_id, body.decision, body.reason, body.lease_token)
    return DecisionPublic(id=row.id, sample_id=sample_id, fit_id=row.fit_id, decision=row.decision,
                          reason=row.reason, state=sample.state, stream=stream.value if stream else None,
                          created_at=row.created_at)


@router.post("/samples/{sample_id}/lease/retake", response_model=LeasePublic)
def retake(sample_id: Id, body: LeaseRequest, session: SessionDep, settings: SettingsDep,
           user: ReviewerUser) -> LeasePublic:
    """Take a lapsed lease again while nobody else holds the sample (409 naming why otherwise)."""
    lease = queues.retake(session, user, sample_id, LeaseKind.review, body.lease_token, settings.lease_seconds)
    return LeasePublic(sample_id=lease.sample_id, lease_token=lease.token, lease_expires_at=lease.expires_at)


@router.get("/samples/{sample_id}/draft", response_model=DraftPublic,
            responses={204: {"description": "No draft of yours for this sample."}})
def get_draft(sample_id: Id, session: SessionDep, user: ReviewerUser) -> Response:
    """Your decision and reason in progress on a sample whose lease you hold."""
    draft = drafts.get(session, user, sample_id, LeaseKind.review)
    return Response(status_code=204) if draft is None else json_response(DraftPublic(**drafts.public(draft)))


@router.put("/samples/{sample_id}/draft", response_model=DraftPublic)
def save_draft(sample_id: Id, body: ReviewDraftIn, session: SessionDep, settings: SettingsDep,
               user: ReviewerUser) -> Response:
    """Save your decision and reason in progress (replacing the previous save); deleted when you submit."""
    draft = drafts.save(session, user, sample_id, LeaseKind.review, body, settings.max_upload_bytes)
    return json_response(DraftPublic(**drafts.public(draft)))


@router.delete("/samples/{sample_id}/draft", status_code=204)
def discard_draft(sample_id: Id, session: SessionDep, user: ReviewerUser) -> None:
    """Throw your draft of a sample away."""
    drafts.discard(session, user, sample_id, LeaseKind.review)
