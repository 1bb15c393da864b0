"""The audit trail: every change made through a service adds one row, in the same transaction."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import insert
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.audit import AuditEvent


def record(session: Session, actor_id: int | None, action: str, entity: str, entity_id: int | str,
           **data: Any) -> None:
    session.add(AuditEvent(actor_id=actor_id, action=action, entity=entity, entity_id=str(entity_id), data=data))


def row(actor_id: int | None, action: str, entity: str, entity_id: int | str, at: datetime | None = None,
        **data: Any) -> dict[str, Any]:
    """One audit row as parameters for `write_rows` (the Core counterpart of `record`)."""
    return {"at": at or utcnow(), "actor_id": actor_id, "action": action, "entity": entity,
            "entity_id": str(entity_id), "data": data}


def write_rows(session: Session, rows: list[dict[str, Any]]) -> None:
    """All of a request's audit rows in one statement (multi-row INSERT), skipping the ORM unit of work:
    used by the annotator hot path, where one round trip per row showed in the profile."""
    if len(rows) == 1:
        session.connection().execute(insert(AuditEvent.__table__), rows[0])
    elif rows:
        # RETURNING makes SQLAlchemy send one multi-row VALUES ("insertmanyvalues") on both backends.
        session.connection().execute(insert(AuditEvent.__table__).returning(AuditEvent.__table__.c.id), rows)
