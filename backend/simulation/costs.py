"""Human time, counted with the paper's unit costs ("Iterative Refinement"): annotating a keypoint takes
about 2 s, correcting a segmentation mask about 12 s, verifying a fit about 5 s. Full manual annotation of
all 21 keypoints across the views takes about 15 minutes per sample ("FreiHAND Dataset")."""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

PAPER_FULL_ANNOTATION_S = 15 * 60.0


@dataclass(frozen=True)
class UnitCosts:
    """Seconds of human work per action (the paper's figures by default)."""

    click_s: float = 2.0
    mask_correction_s: float = 12.0
    verification_s: float = 5.0
    # Accepting a view's proposals with one key (annotate page: Enter). Not a figure of the paper: an assumption,
    # counted only when simulated annotators accept proposals (AnnotatorConfig.accept_proposals_within_px).
    proposal_view_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("click_s", "mask_correction_s", "verification_s", "proposal_view_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= 3600):
                raise ValueError(f"{name} must be a number of seconds in [0, 3600], not {value}")


@dataclass
class RoundEffort:
    """Counts of human actions in one round (mutable tally; see HumanLedger)."""

    clicks: int = 0
    skipped_points: int = 0
    swapped_views: int = 0
    mask_corrections: int = 0
    submissions: int = 0
    verifications: int = 0
    accepts: int = 0
    rejects: int = 0
    sent_to_annotation: int = 0
    discards: int = 0
    reviewer_mistakes: int = 0
    accepted_proposals: int = 0  # keypoints set by accepting a proposal instead of a click
    proposal_views: int = 0  # views where proposals were accepted (one key each)
    accepted_triangulated: int = 0  # of accepted_proposals, the page's triangulation of the annotator's own clicks

    def seconds(self, costs: UnitCosts) -> float:
        return (self.clicks * costs.click_s + self.mask_corrections * costs.mask_correction_s
                + self.verifications * costs.verification_s + self.proposal_views * costs.proposal_view_s)


@dataclass
class HumanLedger:
    """Human actions per round index, and their cost in time. Thread-safe: simulated people may work in
    parallel."""

    costs: UnitCosts = field(default_factory=UnitCosts)
    rounds: dict[int, RoundEffort] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add(self, round_index: int, **counts: int) -> None:
        with self._lock:
            effort = self.rounds.setdefault(round_index, RoundEffort())
            for name, value in counts.items():
                setattr(effort, name, getattr(effort, name) + int(value))

    def effort(self, round_index: int) -> RoundEffort:
        with self._lock:
            return RoundEffort(**vars(self.rounds.get(round_index, RoundEffort())))

    def hours(self, round_index: int | None = None) -> float:
        """Human hours of one round, or of all rounds."""
        with self._lock:
            efforts = self.rounds.values() if round_index is None else [self.rounds.get(round_index, RoundEffort())]
            return sum(e.seconds(self.costs) for e in efforts) / 3600.0
