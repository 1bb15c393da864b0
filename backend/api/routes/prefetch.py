"""Prefetch for both queues: lease the task after the one on screen (services.leases.prefetch)."""

from __future__ import annotations

from fastapi import APIRouter, Response

from backend.api.deps import AnnotatorUser, ReviewerUser, SessionDep, SettingsDep
from backend.api.routes.tasks_common import json_response, task_of
from backend.models.enums import LeaseKind
from backend.schemas.tasks import TaskPublic
from backend.schemas.ui import PrefetchRequest
from backend.services.leases import prefetch
from backend.services.review import label_audits

router = APIRouter(tags=["prefetch"])
EMPTY = {204: {"description": "Nothing more in the queue."}}


@router.post("/annotate/prefetch", response_model=TaskPublic, responses=EMPTY)
def prefetch_annotate(body: PrefetchRequest, session: SessionDep, settings: SettingsDep,
                      user: AnnotatorUser) -> Response:
    """Lease the annotation task after `current_sample_id` (at most two held); `next` returns it once the
    current one is submitted."""
    lease = prefetch.acquire_ahead(session, user, LeaseKind.annotate, settings.lease_seconds, body.current_sample_id)
    return Response(status_code=204) if lease is None else json_response(task_of(session, lease))


@router.post("/review/prefetch", response_model=TaskPublic, responses=EMPTY)
def prefetch_review(body: PrefetchRequest, session: SessionDep, settings: SettingsDep,
                    user: ReviewerUser) -> Response:
    """Lease the review task after `current_sample_id`, with its fit (or a blind audit: review.label_audits)."""
    lease, _ = label_audits.next_review(
        session, user, settings.lease_seconds,
        lambda: prefetch.acquire_ahead(session, user, LeaseKind.review, settings.lease_seconds,
                                       body.current_sample_id), ahead_of=body.current_sample_id)
    return Response(status_code=204) if lease is None else json_response(task_of(session, lease, with_fit=True))
