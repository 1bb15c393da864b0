"""A simulated reviewer: takes fits from the reviewer queue through the API and judges them by their true
error: accept when the fit's mean vertex error against the ground truth is under `accept_below_mm`, with a
decision flipped at `error_rate` (a mistake). From round 1 on, a fit from predictions judged bad is discarded (the
sample waits for the next round's fit, as the paper's reviewers discarded most fits they did not accept) while the
sample has been discarded fewer than `discards_before_annotation` times. In round 0 a bad detector fit is discarded
the same way only once D_0 already holds `round0_discard_floor` labels (None: never; every bad fit goes to the
annotators, D_0 being all that round 1 trains on). Any other bad fit is sent back for annotation until the
sample has had `max_annotation_attempts` annotation passes, then rejected. Each decision costs one verification of
the unit costs."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from backend.simulation.client import ApiClient
from backend.simulation.costs import HumanLedger
from backend.simulation.truth import GroundTruthIndex


@dataclass(frozen=True)
class ReviewerConfig:
    """How a simulated reviewer decides (millimetres; error rate in [0, 1])."""

    accept_below_mm: float = 8.0
    error_rate: float = 0.02
    max_annotation_attempts: int = 2
    # 0: every bad fit goes to the annotators (as before the discard decision existed).
    discards_before_annotation: int = 0
    # Round 0: discard (as above) once D_0 holds this many labels; None: round 0 never discards.
    round0_discard_floor: int | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.accept_below_mm) and 0 < self.accept_below_mm <= 1000):
            raise ValueError(f"accept_below_mm must be in (0, 1000], not {self.accept_below_mm}")
        if not (math.isfinite(self.error_rate) and 0 <= self.error_rate <= 1):
            raise ValueError(f"error_rate must be in [0, 1], not {self.error_rate}")
        if not 0 <= self.max_annotation_attempts <= 100:
            raise ValueError(f"max_annotation_attempts must be in 0..100, not {self.max_annotation_attempts}")
        if not 0 <= self.discards_before_annotation <= 100:
            raise ValueError(f"discards_before_annotation must be in 0..100, not {self.discards_before_annotation}")
        if self.round0_discard_floor is not None and not 0 <= self.round0_discard_floor <= 1_000_000:
            raise ValueError(f"round0_discard_floor must be in 0..1000000 or None, not {self.round0_discard_floor}")

    def may_discard(self, round_index: int, discards_so_far: int,
                    labels_so_far: Callable[[], int] | None = None) -> bool:
        """Whether a bad fit from predictions is discarded (else it goes to the annotators): fewer than
        `discards_before_annotation` discards of the sample so far, and in round 0 D_0 at its floor already
        (`labels_so_far`: the dataset's size now, asked only then; None where not known)."""
        if discards_so_far >= self.discards_before_annotation:
            return False
        if round_index > 0:
            return True
        return (self.round0_discard_floor is not None and labels_so_far is not None
                and labels_so_far() >= self.round0_discard_floor)


@dataclass(frozen=True)
class ReviewOutcome:
    """One decision: what was decided, on what true error, whether it was a mistake, and whether the fit
    came after an annotation pass of this team (else: from predictions)."""

    sample_id: int
    decision: str
    vertex_mm: float
    mistake: bool
    stream: str | None
    after_annotation: bool


class SimulatedReviewer:
    """One reviewer account working through the API."""

    def __init__(self, name: str, client: ApiClient, truth: GroundTruthIndex, ledger: HumanLedger,
                 config: ReviewerConfig | None = None) -> None:
        self.name = name
        self.client = client
        self.truth = truth
        self.ledger = ledger
        self.config = config or ReviewerConfig()
        self.rng = np.random.default_rng([self.config.seed, *name.encode()])

    def review_next(self, round_index: int, annotation_attempts: Mapping[int, int],
                    discards: Mapping[int, int] | None = None,
                    labels_so_far: Callable[[], int] | None = None) -> ReviewOutcome | None:
        """Decide the next fit in the reviewer queue; None when the queue is empty.

        Args:
            annotation_attempts: sample id -> annotation passes it has had (decides annotate vs reject).
            discards: sample id -> times its fit was discarded (decides discard vs annotate).
            labels_so_far: the dataset's size now (read only in round 0, for `round0_discard_floor`).
        """
        task = self.client.next_review()
        if task is None:
            return None
        sample_id = task["sample_id"]
        if not task.get("fit"):
            raise ValueError(f"sample {sample_id} was handed out for review without a fit")
        error = self.truth.fit_errors([sample_id], [task["fit"]["params"]])[0]
        good = error.vertex_mm < self.config.accept_below_mm
        mistake = bool(self.rng.random() < self.config.error_rate)
        if mistake:
            good = not good
        from_predictions = not task["fit"].get("from_annotation", False)
        if good:
            decision, reason = "accept", ""
        elif from_predictions and self.config.may_discard(round_index, (discards or {}).get(sample_id, 0),
                                                          labels_so_far):
            decision, reason = "discard", ""
        elif annotation_attempts.get(sample_id, 0) < self.config.max_annotation_attempts:
            decision, reason = "annotate", "the fit is off; needs clicks"
        else:
            decision, reason = "reject", "the fit is off after annotation"
        result = self.client.decide(sample_id, decision, task["lease_token"], reason)
        self.ledger.add(round_index, verifications=1, accepts=int(decision == "accept"),
                        rejects=int(decision == "reject"), sent_to_annotation=int(decision == "annotate"),
                        discards=int(decision == "discard"),
                        reviewer_mistakes=int(mistake))
        return ReviewOutcome(sample_id=sample_id, decision=decision, vertex_mm=error.vertex_mm, mistake=mistake,
                             stream=result.get("stream"), after_annotation=annotation_attempts.get(sample_id, 0) > 0)
