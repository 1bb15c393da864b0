"""PostgreSQL: the whole of `queues.acquire` in one statement (one round trip instead of six).

Data-modifying CTEs, each gated on the ones before returning nothing (a row-free `NOT EXISTS` is a
one-time filter: when it fails the branch's lock subquery is never run):
- `own`: renew the caller's live lease of the queue (the drafted one first);
- `drafted`: else take a free sample the caller has a draft of;
- `free`: else take the first free sample of the queue (`FOR UPDATE SKIP LOCKED`, as in take_free);
- `aud`: the `lease.acquire` audit row of a new lease;
and the main SELECT returns the taken sample's head columns, its lease token, its sequence's name and one
row per view with the view's newest mask (a LEFT JOIN: a sample without views still comes back).
The conditions and orders are those of the three statements `queues.acquire` runs on SQLite.

Built once per queue kind and process (Core compiles it once; psycopg prepares it server-side after
`prepare_threshold` executions, so PostgreSQL plans it once per connection).
"""

from __future__ import annotations

from functools import cache
from typing import Any

from sqlalchemy import (
    JSON,
    String,
    bindparam,
    cast,
    column,
    exists,
    insert,
    literal_column,
    or_,
    select,
    text,
    union_all,
    update,
)
from sqlalchemy.sql import Select

from backend.db.base import UTCDateTime
from backend.db.statements.passed_over import passed_over
from backend.models.audit import AuditEvent
from backend.models.capture import CameraCalibration, Sample, Sequence, View
from backend.models.drafts import Draft
from backend.models.enums import LeaseKind, SampleState
from backend.models.labels import Mask

_SAMPLES, _DRAFTS, _VIEWS = Sample.__table__, Draft.__table__, View.__table__
QUEUE_STATE = {LeaseKind.annotate: SampleState.needs_annotation, LeaseKind.review: SampleState.in_review}


def queue_order(kind: LeaseKind) -> tuple:
    """The order a queue hands out its free samples in (both databases): reviewers see the most confident first
    (paper); annotators take frames in capture order (by state, fixed by `free_pick`'s range, then id)."""
    c = _SAMPLES.c
    if kind is LeaseKind.review:
        return (c.confidence.desc().nulls_last(), c.id)
    return (c.state, c.id)


def free_pick(kind: LeaseKind, now: Any, *conditions: Any) -> Select:
    """The id of the queue's first free sample (in `queue_order`; a lease that has expired by `now` frees it)
    meeting `conditions`, locked `FOR UPDATE SKIP LOCKED`: rows other transactions hold are passed over."""
    c = _SAMPLES.c
    state = QUEUE_STATE[kind].value
    # The annotate queue reads `state BETWEEN s AND s`, not `state = s`: from an equality PostgreSQL takes the
    # state as constant and drops it from the ORDER BY, and then the primary key reads in id order too. Whenever
    # its statistics said most samples were in the queue (a project's start) it took that path and walked past
    # every sample already done: 6,500 rows filtered per lease by the end of a 30 s `bench api` run. With the
    # range only ix_samples_queue (state, id) gives the order, and the lease reads the queue's head from it.
    in_queue = c.state.between(state, state) if kind is LeaseKind.annotate else c.state == state
    return (select(c.id).where(in_queue, or_(c.lease_expires_at.is_(None), c.lease_expires_at <= now), *conditions)
            .order_by(*queue_order(kind)).limit(1).with_for_update(skip_locked=True))


@cache
def acquire_statement(kind: LeaseKind) -> Select:
    """Parameters: user_id, now, expires, token (the new lease's, used when a free sample is taken).
    Result rows: id, sequence_id, frame_index, time_s, state, current_fit_id, lease_token, sequence,
    side, view_id, camera, width, height, mask_id (view columns NULL when the sample has no views)."""
    c = _SAMPLES.c
    user_id = bindparam("user_id")
    now, expires = bindparam("now", type_=UTCDateTime()), bindparam("expires", type_=UTCDateTime())
    token = bindparam("token", type_=String())
    state = QUEUE_STATE[kind].value
    head = (c.id, c.sequence_id, c.frame_index, c.time_s, c.state, c.current_fit_id, c.lease_token)

    drafted = exists().where(_DRAFTS.c.sample_id == c.id, _DRAFTS.c.kind == kind.value, _DRAFTS.c.user_id == user_id)
    mine = (c.leased_by_id == user_id, c.lease_kind == kind.value, c.state == state, c.lease_expires_at > now)
    own = (update(_SAMPLES)
           .where(c.id == select(c.id).where(*mine).order_by(drafted.desc(), c.id).limit(1).scalar_subquery(), *mine)
           .values(lease_expires_at=expires, updated_at=now).returning(*head).cte("own"))

    def take(cte_name: str, *conditions, before: tuple) -> object:
        pick = free_pick(kind, now, *conditions)
        return (update(_SAMPLES)
                .where(c.id == pick.scalar_subquery(), *(~exists(select(b.c.id)) for b in before))
                .values(leased_by_id=user_id, lease_kind=kind.value, lease_token=token, lease_expires_at=expires,
                        updated_at=now)
                .returning(*head).cte(cte_name))

    mine_drafts = select(_DRAFTS.c.sample_id).where(_DRAFTS.c.user_id == user_id, _DRAFTS.c.kind == kind.value)
    # Not a sample this person skipped or whose fit failed on their work: it goes to someone else (issue 38).
    fresh = (passed_over(c.id, user_id),) if kind is LeaseKind.annotate else ()
    drafted_free = take("drafted", c.id.in_(mine_drafts), *fresh, before=(own,))
    free = take("free", *fresh, before=(own, drafted_free))

    new = union_all(select(drafted_free.c.id), select(free.c.id)).subquery("new")
    a = AuditEvent.__table__.c
    aud = insert(AuditEvent.__table__).from_select(
        [a.at, a.actor_id, a.action, a.entity, a.entity_id, a.data],
        select(now, user_id, literal_column("'lease.acquire'"), literal_column("'sample'"), cast(new.c.id, String),
               bindparam("audit_data", {"kind": kind.value}, type_=JSON()))
    ).cte("aud")

    # The three branches' rows as `SELECT *` and the views joined directly, not as labelled subqueries: the
    # statement's text stays under psycopg's 4 KiB query cache (beyond it the text is parsed again on every
    # execution; at 4.3 KiB it was ~0.6 ms of the cycle). The CTEs are named to the compiler with add_cte.
    taken = (text("SELECT * FROM own UNION ALL SELECT * FROM drafted UNION ALL SELECT * FROM free")
             .columns(*(column(col.name, col.type) for col in head)).subquery("taken"))
    v = _VIEWS.c
    newest = (select(Mask.id).where(Mask.view_id == v.id).order_by(Mask.version.desc()).limit(1)
              .correlate(_VIEWS).scalar_subquery())
    cameras = CameraCalibration.__table__
    return (select(*taken.c, Sequence.external_id.label("sequence"), Sequence.side, v.id.label("view_id"),
                   cameras.c.name.label("camera"), v.width, v.height, newest.label("mask_id"))
            .select_from(taken.outerjoin(_VIEWS, v.sample_id == taken.c.id)
                         .outerjoin(cameras, cameras.c.id == v.camera_id)
                         .outerjoin(Sequence.__table__, Sequence.id == taken.c.sequence_id))
            .order_by(v.id)
            .add_cte(own, drafted_free, free, aud))

