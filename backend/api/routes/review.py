from __future__ import annotations

from fastapi import APIRouter, Response

from backend.api.deps import ReviewerUser, SessionDep, SettingsDep
from backend.api.routes.leases import lease_routes
from backend.api.routes.tasks_common import task_of
from backend.models.enums import LeaseKind
from backend.schemas.base import Id
from backend.schemas.drafts import ReviewDraftIn
from backend.schemas.tasks import DecisionCreate, DecisionPublic, TaskPublic
from backend.services.leases import queues
from backend.services.review import label_audits, review

router = APIRouter(prefix="/review", tags=["reviewer queue"])
router.include_router(lease_routes(LeaseKind.review, ReviewerUser, ReviewDraftIn, "decision and reason",
                                   label_audits.retake))


@router.post("/next", response_model=TaskPublic, responses={204: {"description": "The queue is empty."}})
def next_task(session: SessionDep, settings: SettingsDep, user: ReviewerUser) -> TaskPublic | Response:
    """Lease the most confident sample awaiting verification, with its fit (blind audits of accepted labels
    interleaved, shown as any task: services.review.label_audits)."""
    lease, _ = label_audits.next_review(
        session, user, settings.lease_seconds,
        lambda: queues.acquire(session, user, LeaseKind.review, settings.lease_seconds))
    if lease is None:
        return Response(status_code=204)
    return task_of(session, lease, with_fit=True)


@router.post("/samples/{sample_id}/decision", response_model=DecisionPublic, status_code=201)
def decide(sample_id: Id, body: DecisionCreate, session: SessionDep, user: ReviewerUser) -> DecisionPublic:
    """Accept, reject, or send back for annotation (with a reason) a sample whose review lease you hold, or discard
    a fit from predictions (the sample waits for the next round's fit; 409 for a fit that used annotators' clicks).
    On a gold label (`recorded_as` 'gold_answer') the decision is your answer to it and the sample does not move."""
    row, sample, stream, gold_answer = review.decide(session, user, sample_id, body.decision, body.reason,
                                                     body.lease_token)
    return DecisionPublic(id=row.id, sample_id=sample_id, fit_id=row.fit_id, decision=row.decision,
                          reason=row.reason, state=sample.state, stream=stream.value if stream else None,
                          created_at=row.created_at, recorded_as="gold_answer" if gold_answer else "review")
