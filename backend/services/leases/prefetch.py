"""Prefetch: lease the task after the current one, so the browser can load it before it is needed.

A user may hold at most `MAX_HELD` live leases per queue: the sample on screen and the one prefetched.
The prefetched lease is an ordinary lease (same columns, same expiry, same refusal of a second holder),
so `services.leases.queues.acquire` hands it back as the caller's "next" once the current sample has left the
queue (submitted or decided), and it returns to the queue by itself if it expires unused.
"""

from __future__ import annotations

from datetime import datetime, timedelta

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.capture import Sample
from backend.models.enums import LeaseKind
from backend.services.accounts.users import Actor
from backend.services.leases.queues import HEAD_COLUMNS, QUEUE_STATE, Lease, SampleHead, take_free

MAX_HELD = 2
_SAMPLES = Sample.__table__


def acquire_ahead(session: Session, user: Actor, kind: LeaseKind, lease_seconds: int, current_sample_id: int,
                  now: datetime | None = None) -> Lease | None:
    """The caller's other live lease of this kind (renewed) if it holds one besides `current_sample_id`,
    else a new lease on the next free sample while it holds fewer than `MAX_HELD`; None if the queue has
    nothing more."""
    now = now or utcnow()
    expires = now + timedelta(seconds=lease_seconds)
    state = QUEUE_STATE[kind].value
    c = _SAMPLES.c
    conn = session.connection()
    mine = (c.leased_by_id == user.id, c.lease_kind == kind.value, c.state == state, c.lease_expires_at > now)
    other = conn.execute(
        update(_SAMPLES)
        .where(c.id == select(c.id).where(*mine, c.id != current_sample_id).order_by(c.id).limit(1)
               .scalar_subquery(), *mine)
        .values(lease_expires_at=expires)
        .returning(*HEAD_COLUMNS, c.lease_token)
    ).first()
    if other is not None:
        return Lease(other.id, other.lease_token, expires, kind, SampleHead(*other[:6]))
    held = conn.execute(select(func.count()).select_from(_SAMPLES).where(*mine)).scalar_one()
    if held >= MAX_HELD:
        return None
    return take_free(session, user, kind, expires, now, action="lease.prefetch", exclude_sample_id=current_sample_id)
