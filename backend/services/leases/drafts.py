"""Drafts: work in progress on a leased sample, saved as the person works (the browser debounces), so a
reload, another tab, the Back button or a new login restores it.

A draft is read only while holding a live lease of that queue on the sample. The author reads their own; work
left on a lease that lapsed travels with the sample: whoever holds it next reads the newest such draft (naming
who left it) until they save their own, so nobody redoes points already placed. Each save is a new revision;
a save made on an older revision than one another page stored is refused (two tabs never overwrite each other
silently). Submitting (or deciding) deletes the sample's drafts of that queue; an author may also discard their
own.
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
from backend.models.users import User
from backend.schemas.drafts import AnnotateDraftIn, ReviewDraftIn
from backend.services.accounts.users import Actor
from backend.services.errors import ConflictError, NotFoundError, TooLargeError
from backend.services.leases import queues
from backend.services.leases.annotation_input import check_clicks, check_masks

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
    left_out = {"lease_token", "base_revision"} | ({"writer"} if body.writer is None else set())
    payload = body.model_dump(mode="json", exclude=left_out)
    size = len(json.dumps(payload, separators=(",", ":")))
    if size > max_bytes:
        raise TooLargeError(f"draft of sample {sample_id} is {size} bytes; at most {max_bytes}")
    draft = _own(session, user, sample_id, kind)
    _check_version(draft, body, sample_id)
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


def _check_version(draft: Draft | None, body: AnnotateDraftIn | ReviewDraftIn, sample_id: int) -> None:
    """A save made on an older revision than the stored one, which another page (writer) saved, is the second of two
    concurrent edits: refused (409) so neither is lost silently; the page shows both and the person keeps one."""
    if draft is None or body.base_revision is None or draft.revision == body.base_revision:
        return
    if body.writer is not None and draft.payload.get("writer") == body.writer:
        return  # this page's own earlier save answered after it sent this one (a resend as the page goes)
    raise ConflictError(f"your draft of sample {sample_id} was saved from another tab or window (revision "
                        f"{draft.revision}) after revision {body.base_revision}, which this page's work was made on; "
                        "nothing was written: compare the two and keep one")


def get(session: Session, user: Actor, sample_id: int, kind: LeaseKind) -> Draft | None:
    """The caller's draft of the sample, else the work someone left on it on a lease that lapsed (the newest such
    draft: it travels with the sample to whoever takes it next), or None; refused unless the caller holds a live
    `kind` lease on it (so the one who left it holds none: theirs lapsed)."""
    sample = session.get(Sample, sample_id)  # no lock: a GET reads in a read-only transaction
    if sample is None:
        raise NotFoundError(f"sample {sample_id} not found")
    queues.check_lease(sample, user, kind, None)
    return _own(session, user, sample_id, kind) or _left_by_others(session, user, sample_id, kind)


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


def public(draft: Draft, left_by: str | None = None) -> dict[str, Any]:
    return {"sample_id": draft.sample_id, "kind": draft.kind, "revision": draft.revision,
            "lease_token": draft.lease_token, "updated_at": draft.updated_at, "payload": draft.payload,
            "left_by": left_by}


def read(session: Session, user: Actor, sample_id: int, kind: LeaseKind) -> dict[str, Any] | None:
    """`get` in the API's form: a draft someone else left names them (`left_by`)."""
    draft = get(session, user, sample_id, kind)
    if draft is None:
        return None
    left_by = None
    if draft.user_id != user.id:
        person = session.get(User, draft.user_id)
        left_by = (person.full_name or person.email) if person is not None else f"user {draft.user_id}"
    return public(draft, left_by)


def _left_by_others(session: Session, user: Actor, sample_id: int, kind: LeaseKind) -> Draft | None:
    return session.execute(select(Draft).where(Draft.sample_id == sample_id, Draft.kind == kind.value,
                                               Draft.user_id != user.id)
                           .order_by(Draft.updated_at.desc(), Draft.id.desc()).limit(1)).scalar_one_or_none()


def _own(session: Session, user: Actor, sample_id: int, kind: LeaseKind) -> Draft | None:
    return session.execute(select(Draft).where(Draft.sample_id == sample_id, Draft.kind == kind.value,
                                               Draft.user_id == user.id)).scalar_one_or_none()
