from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, Response

from backend.api.deps import AnnotatorUser, JobQueueDep, SessionDep, SettingsDep, StorageDep, state_session
from backend.api.routes.leases import lease_routes
from backend.api.routes.tasks_common import json_response, task_of
from backend.models.enums import FlagKind, LeaseKind
from backend.schemas.base import Id
from backend.schemas.drafts import AnnotateDraftIn
from backend.schemas.tasks import (
    FitFailurePublic,
    SkipCreate,
    SkipPublic,
    SubmissionCreate,
    SubmissionPublic,
    TaskPublic,
)
from backend.services.accounts.users import Principal
from backend.services.labeling import submissions
from backend.services.leases import annotation_flags, queues

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


@router.post("/samples/{sample_id}/skip", response_model=SkipPublic)
def skip(sample_id: Id, body: SkipCreate, session: SessionDep, user: AnnotatorUser) -> SkipPublic:
    """Pass on a leased sample with a reason: 'skip' (it goes to another annotator, never back to you) or
    'no_hand' (no hand in any view: out of the queue as rejected). Nothing is submitted or fitted."""
    result = annotation_flags.pass_on(session, user, sample_id, FlagKind(body.kind), body.reason, body.lease_token)
    return SkipPublic(sample_id=result.sample_id, kind=result.kind.value, state=result.state)


@router.get("/fit-failures", response_model=list[FitFailurePublic])
def fit_failures(session: SessionDep, user: AnnotatorUser) -> list[FitFailurePublic]:
    """The fits that failed on your submissions, newest first (at most 10), with why: the page shows them."""
    return [FitFailurePublic(**f) for f in annotation_flags.fit_failures_of(session, user)]


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
