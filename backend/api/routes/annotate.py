from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, Response

from backend.api.deps import AnnotatorUser, JobQueueDep, SettingsDep, StorageDep, state_session
from backend.api.routes.leases import lease_routes
from backend.api.routes.tasks_common import json_response, task_of
from backend.models.enums import LeaseKind
from backend.schemas.base import Id
from backend.schemas.drafts import AnnotateDraftIn
from backend.schemas.tasks import SubmissionCreate, SubmissionPublic, TaskPublic
from backend.services import queues, submissions
from backend.services.users import Principal

router = APIRouter(prefix="/annotate", tags=["annotator queue"])
router.include_router(lease_routes(LeaseKind.annotate, AnnotatorUser, AnnotateDraftIn, "clicks and masks"))


@router.post("/next", response_model=TaskPublic, responses={204: {"description": "The queue is empty."}})
def next_task(request: Request, settings: SettingsDep, user: AnnotatorUser) -> Response:
    """Lease the next sample needing annotation (or return the one you already hold, renewed)."""
    return next_response(request.app.state, user)


@router.post("/samples/{sample_id}/submissions", response_model=SubmissionPublic, status_code=201,
             responses={200: {"description": "Already submitted with this submission_id: nothing new written."}})
def submit(sample_id: Id, body: SubmissionCreate, request: Request, settings: SettingsDep, queue: JobQueueDep,
           storage: StorageDep, user: AnnotatorUser) -> Response:
    """Clicks and mask corrections for a leased sample; queues a fit. Idempotent on `submission_id`."""
    return submit_response(request.app.state, user, sample_id, body)


# The two routes' work, in the route's thread; backend.api.hot_path calls them too, without FastAPI's layers.
def next_response(state: Any, user: Principal) -> Response:
    """`POST /annotate/next` for `user` on the app's `state` (settings, session factory)."""
    with state_session(state) as session:
        lease = queues.acquire(session, user, LeaseKind.annotate, state.settings.lease_seconds, sole_statement=True)
        if lease is None:
            return Response(status_code=204)
        task = task_of(session, lease)  # PostgreSQL: built from the lease statement's rows alone
    return json_response(task)


def submit_response(state: Any, user: Principal, sample_id: int, body: SubmissionCreate) -> Response:
    """`POST /annotate/samples/{sample_id}/submissions` for `user` on the app's `state`."""
    with state_session(state) as session:
        result = submissions.submit(session, state.job_queue, state.storage, user, sample_id, body,
                                    state.settings.max_clicks_per_submission, sole_statement=True)
    s = result.submission
    public = SubmissionPublic.model_construct(
        id=s.id, submission_id=s.client_id, sample_id=s.sample_id, n_clicks=s.n_clicks, n_masks=s.n_masks,
        fit_job_id=s.fit_job_id, duplicate=result.duplicate, created_at=s.created_at)
    return json_response(public, status_code=200 if result.duplicate else 201)
