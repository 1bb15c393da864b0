"""Choosing which samples people annotate: an admin queues unlabeled samples for annotation, e.g. the
initial set D_0 (paper, "Iterative Refinement": D_0 comes from manual annotations of a subset) or more
frames later. Samples left 'unlabeled' are what the rounds predict and fit."""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import Sample
from backend.models.enums import SampleState
from backend.services import audit
from backend.services.captures.state_machine import transition
from backend.services.errors import ConflictError, InvalidInputError, NotFoundError


def queue_for_annotation(session: Session, sample_ids: Sequence[int], actor_id: int | None) -> list[int]:
    """Move the given 'unlabeled' samples to 'needs_annotation'; all or nothing.

    Raises NotFoundError naming unknown ids, ConflictError naming samples in another state.
    """
    if not sample_ids:
        raise InvalidInputError("sample_ids is empty")
    wanted = list(dict.fromkeys(int(i) for i in sample_ids))
    rows = {s.id: s for s in session.execute(select(Sample).where(Sample.id.in_(wanted)).order_by(Sample.id)
                                             .with_for_update()).scalars()}
    if missing := [i for i in wanted if i not in rows]:
        raise NotFoundError(f"samples not found: {missing[:20]}{' ...' if len(missing) > 20 else ''}")
    if busy := [(i, rows[i].state) for i in wanted if rows[i].state != SampleState.unlabeled]:
        shown = ", ".join(f"{i} is '{state}'" for i, state in busy[:20])
        raise ConflictError(f"only unlabeled samples can be queued for annotation: {shown}"
                            f"{' ...' if len(busy) > 20 else ''}")
    for sample_id in wanted:
        transition(session, rows[sample_id], SampleState.needs_annotation, actor_id, reason="queued by an admin")
    audit.record(session, actor_id, "samples.queue_annotation", "sample", wanted[0], count=len(wanted))
    return wanted
