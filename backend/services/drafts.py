"""Drafts: work in progress on a leased sample, saved as the person works (the browser debounces), so a
reload, another tab, the Back button or a new login restores it.

Only the author sees a draft, and only while holding a live lease of that queue on the sample: the lease
is what makes the work theirs, so a draft left on a lease that lapsed and went to someone else is never
applied to the new holder's work. Submitting (or deciding) deletes the sample's drafts of that queue; an
author may also discard their own.
"""

from __future__ import annotations

import json
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.capture import Sample, View
from backend.models.drafts import Draft
from backend.models.enums import LeaseKind
from backend.schemas.drafts import AnnotateDraftIn, ReviewDraftIn
from backend.services import queues
from backend.services.annotation_input import check_clicks, check_masks
from backend.services.errors import NotFoundError, TooLargeError
from backend.services.users import Actor

MAX_DRAFT_BYTES = 8 * 1024 * 1024  # the stored JSON; as large as the biggest request body by default


def save(session: Session, user: Actor, sample_id: int, kind: LeaseKind, body: AnnotateDraftIn | ReviewDraftIn,
         max_bytes: int = MAX_DRAFT_BYTES) -> Draft:
    """Store `body` as the caller's draft of the sample (replacing the previous one; revision + 1).

    Refused, writing nothing, unless the caller holds a live `kind` lease on the sample with this token
    (403 / 409 as for a submission), when a click or mask does not fit the sample's views (422), or when
    the stored form would exceed `max_bytes` (413)."""
    sample = queues.load_locked(session, sample_id)  # serialises two tabs saving the same draft
    queues.check_lease(sample, user, kind, body.lease_token)
    if isinstance(body, AnnotateDraftIn):
        views = {v.id: (v.width, v.height) for v in session.execute(
            select(View.id, View.width, View.height).where(View.sample_id == sample_id)).all()}
        check_clicks(views, body.clicks, sample_id)
        check_masks(views, body.masks, sample_id)
    payload = body.model_dump(mode="json", exclude={"lease_token"})
    size = len(json.dumps(payload, separators=(",", ":")))
    if size > max_bytes:
        raise TooLargeError(f"draft of sample {sample_id} is {size} bytes; at most {max_bytes}")
    draft = _own(session, user, sample_id, kind)
    now = utcnow()
    if draft is None:
        draft = Draft(sample_id=sample_id, kind=kind.value, user_id=user.id, lease_token=body.lease_token,
                      revision=1, payload=payload, size_bytes=size, created_at=now, updated_at=now)
        session.add(draft)
    else:
        draft.lease_token = body.lease_token
        draft.revision += 1
        draft.payload = payload
        draft.size_bytes = size
        draft.updated_at = now
    session.flush()
    return draft


def get(session: Session, user: Actor, sample_id: int, kind: LeaseKind) -> Draft | None:
    """The caller's draft of the sample, or None; refused unless they hold a live `kind` lease on it."""
    sample = session.get(Sample, sample_id)  # no lock: a GET reads in a read-only transaction
    if sample is None:
        raise NotFoundError(f"sample {sample_id} not found")
    queues.check_lease(sample, user, kind, None)
    return _own(session, user, sample_id, kind)


def discard(session: Session, user: Actor, sample_id: int, kind: LeaseKind) -> bool:
    """Delete the caller's own draft of the sample (theirs to throw away, lease or not); False if none."""
    queues.load_locked(session, sample_id)  # 404 for an unknown sample
    result = session.execute(delete(Draft).where(Draft.sample_id == sample_id, Draft.kind == kind.value,
                                                 Draft.user_id == user.id))
    return bool(result.rowcount)


def delete_for_sample(session: Session, sample_id: int, kind: LeaseKind) -> None:
    """Every draft of the sample in that queue: called when its work is submitted or decided."""
    session.connection().execute(delete(Draft.__table__).where(Draft.__table__.c.sample_id == sample_id,
                                                               Draft.__table__.c.kind == kind.value))


def public(draft: Draft) -> dict[str, Any]:
    return {"sample_id": draft.sample_id, "kind": draft.kind, "revision": draft.revision,
            "lease_token": draft.lease_token, "updated_at": draft.updated_at, "payload": draft.payload}


def _own(session: Session, user: Actor, sample_id: int, kind: LeaseKind) -> Draft | None:
    return session.execute(select(Draft).where(Draft.sample_id == sample_id, Draft.kind == kind.value,
                                               Draft.user_id == user.id)).scalar_one_or_none()
