"""Time per action, as the browser measured it: what the paper prices (about 2 s per keypoint click,
12 s per mask correction, 5 s per verification) measured on our own UI.

One `ui.activity` audit event per submission or decision, written by its author after it was stored;
the event keeps the action log and a summary that the admin dashboard averages.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.audit import AuditEvent
from backend.models.labels import Submission
from backend.models.review import Decision
from backend.schemas.ui import ActivityCreate
from backend.services import audit
from backend.services.accounts.users import Actor
from backend.services.errors import InvalidInputError, NotFoundError, PermissionDeniedError

ACTION = "ui.activity"
KEYPOINT_ACTIONS = frozenset({"click", "accept", "drag", "occlude", "not_annotated"})
MASK_ACTIONS = frozenset({"brush", "erase"})


def summarise(body: ActivityCreate) -> dict[str, Any]:
    """Seconds spent on keypoints and on masks (each action's duration is the time since the previous
    one, capped by the browser so idle time does not count), and how many of each were done."""
    keypoint_ms = sum(a.duration_ms for a in body.actions if a.kind in KEYPOINT_ACTIONS)
    mask_ms = sum(a.duration_ms for a in body.actions if a.kind in MASK_ACTIONS)
    keypoints = {(a.view_id, a.keypoint) for a in body.actions if a.kind in KEYPOINT_ACTIONS}
    masks = {a.view_id for a in body.actions if a.kind in MASK_ACTIONS}
    return {"time_spent_s": round(body.time_spent_s, 3), "keypoints_set": len(keypoints),
            "keypoint_s": round(keypoint_ms / 1000, 3), "masks_corrected": len(masks),
            "mask_s": round(mask_ms / 1000, 3), "actions": len(body.actions)}


def record(session: Session, user: Actor, body: ActivityCreate) -> tuple[int, bool]:
    """Store the log of a submission or decision made by `user`; (event id, duplicate). A second log for
    the same submission or decision changes nothing."""
    if body.context == "annotate":
        if body.submission_id is None:
            raise InvalidInputError("an annotate activity log needs the submission_id it belongs to")
        row = session.execute(select(Submission).where(Submission.client_id == body.submission_id)).scalar_one_or_none()
        if row is None:
            raise NotFoundError(f"submission {body.submission_id!r} not found")
        owner, sample_id, entity, entity_id = row.user_id, row.sample_id, "submission", row.id
    else:
        if body.decision_id is None:
            raise InvalidInputError("a review activity log needs the decision_id it belongs to")
        decision = session.get(Decision, body.decision_id)
        if decision is None:
            raise NotFoundError(f"decision {body.decision_id} not found")
        owner, sample_id, entity, entity_id = decision.user_id, decision.sample_id, "decision", decision.id
    if owner != user.id:
        raise PermissionDeniedError(f"this {entity} is not yours; log your own work only")
    if sample_id != body.sample_id:
        raise InvalidInputError(f"{entity} {entity_id} belongs to sample {sample_id}, not {body.sample_id}")
    existing = session.execute(select(AuditEvent.id).where(AuditEvent.action == ACTION, AuditEvent.entity == entity,
                                                           AuditEvent.entity_id == str(entity_id))).first()
    if existing is not None:
        return existing[0], True
    actions = [a.model_dump(exclude_none=True) for a in body.actions]
    audit.record(session, user.id, ACTION, entity, entity_id, context=body.context, sample_id=sample_id,
                 summary=summarise(body), log=actions)
    session.flush()
    event_id = session.execute(select(AuditEvent.id).where(AuditEvent.action == ACTION, AuditEvent.entity == entity,
                                                           AuditEvent.entity_id == str(entity_id))).scalar_one()
    return event_id, False
