"""String enums stored as short strings, with CHECK constraints, on both backends."""

from __future__ import annotations

from enum import StrEnum

from sqlalchemy import CheckConstraint


class Role(StrEnum):
    """Ranked: each role may do what the roles below it may."""

    annotator = "annotator"
    reviewer = "reviewer"
    admin = "admin"

    @property
    def rank(self) -> int:
        return ROLE_RANK[self]


ROLE_RANK = {Role.annotator: 0, Role.reviewer: 1, Role.admin: 2}


class SampleState(StrEnum):
    unlabeled = "unlabeled"
    needs_annotation = "needs_annotation"
    annotated = "annotated"
    fitting = "fitting"
    fitted = "fitted"
    in_review = "in_review"
    accepted = "accepted"
    rejected = "rejected"


class FlagKind(StrEnum):
    """What an annotator said instead of clicking, or a fit that failed on their work (models.flags)."""

    no_hand_view = "no_hand_view"
    no_hand = "no_hand"
    skip = "skip"
    fit_failed = "fit_failed"
    agreement = "agreement"  # the first look of an agreement pair: the second goes to another annotator


class Split(StrEnum):
    train = "train"
    evaluation = "evaluation"


class HandSide(StrEnum):
    """Which hand a sequence shows: its fits use that side's hand model (issue 18)."""

    right = "right"
    left = "left"


class LeaseKind(StrEnum):
    annotate = "annotate"
    review = "review"


class Visibility(StrEnum):
    visible = "visible"
    occluded = "occluded"
    not_annotated = "not_annotated"


class MaskKind(StrEnum):
    chroma_key = "chroma_key"
    predicted = "predicted"
    corrected = "corrected"
    model = "model"


class DecisionKind(StrEnum):
    accept = "accept"
    reject = "reject"
    annotate = "annotate"
    # The paper's "discarding the sample": the fit from predictions is not good enough; the sample stays in the pool
    # for the next round's networks (no annotators' time, nothing final).
    discard = "discard"


class Stream(StrEnum):
    """The paper's streams into D_{i+1}: heuristic (D^h), manual (D^m), annotated (D^l)."""

    heuristic = "heuristic"
    manual = "manual"
    annotated = "annotated"


class RoundState(StrEnum):
    running = "running"
    completed = "completed"
    cancelled = "cancelled"
    failed = "failed"  # its job failed; the round before it was reopened (services.jobs.round_failure)


class JobState(StrEnum):
    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"


class JobKind(StrEnum):
    fit = "fit"
    predict = "predict"
    train = "train"
    round = "round"
    import_capture = "import_capture"
    export = "export"
    preannotate = "preannotate"  # round 0 without clicks: detector -> triangulation -> fit (issue 15)


def enum_check(column: str, enum: type[StrEnum], name: str | None = None) -> CheckConstraint:
    values = ", ".join(f"'{member.value}'" for member in enum)
    return CheckConstraint(f"{column} IN ({values})", name=name or f"{column}_valid")
