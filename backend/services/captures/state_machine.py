"""The sample life cycle; the server moves samples only along these edges.

    unlabeled ---------> needs_annotation -> annotated -> fitting -> fitted -> in_review -> accepted
        |                      ^                           |  ^        |  |        |    -> rejected
        +--(predictions)-------|-------------------------> +  |        |  +--> accepted   (heuristic)
                               +----- fit failed ----------+  |        |
                               +------------------------------|--------+----------- annotate
                               +-- no hand (annotator) --> rejected
                               +-- agreement's first look, no second annotator left --> in_review
                                                              +-- refit (new predictions)

No skipping: nothing reaches `accepted` without a fit, and only reviewers (or the heuristic) accept; an accepted
sample leaves `accepted` only by an audit that finds its label wrong (-> rejected or needs_annotation).
"""

from __future__ import annotations

from sqlalchemy.orm import Session

from backend.models.capture import Sample
from backend.models.enums import SampleState as S
from backend.services import audit
from backend.services.errors import ConflictError

TRANSITIONS: dict[S, frozenset[S]] = {
    S.unlabeled: frozenset({S.needs_annotation, S.fitting}),
    # rejected: an annotator saw no hand in it; in_review: an agreement pair's first look, held for a second look
    # nobody is left to take, goes to review with its fit (services.review.agreement.release_stranded).
    S.needs_annotation: frozenset({S.annotated, S.rejected, S.in_review}),
    S.annotated: frozenset({S.fitting}),
    S.fitting: frozenset({S.fitted, S.needs_annotation}),
    S.fitted: frozenset({S.in_review, S.accepted, S.fitting, S.needs_annotation}),
    S.in_review: frozenset({S.accepted, S.rejected, S.needs_annotation, S.fitted}),
    # Only a blind audit that finds the label wrong takes it out again (services.review.label_audits, issue 40).
    S.accepted: frozenset({S.rejected, S.needs_annotation}),
    S.rejected: frozenset(),
}


def can_transition(current: S | str, target: S | str) -> bool:
    return S(target) in TRANSITIONS[S(current)]


def check_path(sample_id: int, current: S | str, *targets: S) -> None:
    """Raise ConflictError (as `transition` would) unless `current` may move through `targets` in order;
    for callers that update the row with one statement and write the audit rows themselves."""
    state = S(current)
    for target in targets:
        if not can_transition(state, target):
            raise ConflictError(f"sample {sample_id} is '{state}'; it cannot become '{target}'")
        state = target


def transition(session: Session, sample: Sample, target: S, actor_id: int | None, reason: str = "") -> None:
    """Move `sample` to `target` or raise ConflictError naming both states; audited."""
    current = S(sample.state)
    if not can_transition(current, target):
        raise ConflictError(f"sample {sample.id} is '{current}'; it cannot become '{target}'")
    sample.state = target
    audit.record(session, actor_id, "sample.state", "sample", sample.id, **{"from": current.value,
                 "to": target.value, "reason": reason})
