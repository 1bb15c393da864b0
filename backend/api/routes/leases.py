"""The lease and draft routes both queues share: renew, release and retake a lease; read, save and discard
your draft of the sample it holds. One router factory, included by annotate.py and review.py.

No `from __future__ import annotations` here: FastAPI reads the routes' parameter types from their annotations,
and the queue's user dependency and draft body are the factory's arguments, which a string annotation
could not name.
"""

from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, Response

from backend.api.deps import SessionDep, SettingsDep
from backend.api.routes.tasks_common import json_response
from backend.models.enums import LeaseKind
from backend.schemas.base import Id, Strict
from backend.schemas.drafts import DraftPublic
from backend.schemas.tasks import LeasePublic, LeaseRequest
from backend.services.leases import drafts, queues


def lease_routes(kind: LeaseKind, user_dep: Any, draft_body: type[Strict], draft_contents: str,
                 retake_lease: Callable[..., queues.Lease] | None = None) -> APIRouter:
    """The shared routes under `/samples/{sample_id}` for the queue of `kind`.

    `user_dep` is the queue's role dependency (AnnotatorUser, ReviewerUser); `draft_body` the schema of its
    drafts; `draft_contents` what a draft holds, as the routes' descriptions say it ("your clicks and masks").
    `retake_lease(session, user, sample_id, token, lease_seconds)`: the queue's own retake where it holds more than
    its state's samples (review: blind audits of accepted labels); by default `queues.retake`.
    The handlers keep their names: the OpenAPI operation ids are made from them and the path.
    """
    router = APIRouter()

    @router.post("/samples/{sample_id}/lease/renew", response_model=LeasePublic)
    def renew(sample_id: Id, body: LeaseRequest, session: SessionDep, settings: SettingsDep,
              user: user_dep) -> LeasePublic:
        lease = queues.renew(session, user, sample_id, kind, body.lease_token, settings.lease_seconds)
        return LeasePublic(sample_id=lease.sample_id, lease_token=lease.token, lease_expires_at=lease.expires_at)

    @router.post("/samples/{sample_id}/lease/release", status_code=204)
    def release(sample_id: Id, body: LeaseRequest, session: SessionDep, user: user_dep) -> None:
        queues.release(session, user, sample_id, kind, body.lease_token)

    @router.post("/samples/{sample_id}/lease/retake", response_model=LeasePublic)
    def retake(sample_id: Id, body: LeaseRequest, session: SessionDep, settings: SettingsDep,
               user: user_dep) -> LeasePublic:
        """Take a lapsed lease again while nobody else holds the sample (409 naming why otherwise)."""
        if retake_lease is None:
            lease = queues.retake(session, user, sample_id, kind, body.lease_token, settings.lease_seconds)
        else:
            lease = retake_lease(session, user, sample_id, body.lease_token, settings.lease_seconds)
        return LeasePublic(sample_id=lease.sample_id, lease_token=lease.token, lease_expires_at=lease.expires_at)

    @router.get("/samples/{sample_id}/draft", response_model=DraftPublic,
                responses={204: {"description": "No draft of yours for this sample."}},
                description=f"Your {draft_contents} in progress on a sample whose lease you hold.")
    def get_draft(sample_id: Id, session: SessionDep, user: user_dep) -> Response:
        draft = drafts.read(session, user, sample_id, kind)
        return Response(status_code=204) if draft is None else json_response(DraftPublic(**draft))

    @router.put("/samples/{sample_id}/draft", response_model=DraftPublic,
                description=f"Save your {draft_contents} in progress (replacing the previous save); deleted when "
                            "you submit.")
    def save_draft(sample_id: Id, body: draft_body, session: SessionDep, settings: SettingsDep,
                   user: user_dep) -> Response:
        draft = drafts.save(session, user, sample_id, kind, body, settings.max_upload_bytes)
        return json_response(DraftPublic(**drafts.public(draft)))

    @router.delete("/samples/{sample_id}/draft", status_code=204)
    def discard_draft(sample_id: Id, session: SessionDep, user: user_dep) -> None:
        """Throw your draft of a sample away."""
        drafts.discard(session, user, sample_id, kind)

    return router
