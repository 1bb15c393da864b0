"""A precision target instead of fixed thresholds (issue 40): the admin sets "at most X % of auto-accepted labels
wrong"; each round the heuristic's thresholds are chosen from the evidence so far so that the Wilson 95 % upper bound
of the wrong share among the labels they would accept stays under X.

The evidence: labels whose heuristic metrics are known (fits from predictions) and whose rightness a person judged:
blind audits of accepted labels (services.review.label_audits: correct / wrong) and reviewers' decisions on fits the
heuristic did not accept (accept: right; reject, send back: wrong). The candidates are the paper's thresholds scaled
along one line (`scaled`: confidences and IoUs move their gap to 1 by the factor, distances by it; scale 1 is the
paper's), from strict (0.5) to loose (2). The loosest candidate whose accepted evidence numbers at least
`min_audits_for_target` labels with an upper bound at most the target is chosen; without enough evidence (fewer
audited heuristic labels than that) or when no candidate qualifies, the paper's thresholds stay. The evidence is not
a random sample beyond the current thresholds (reviewers see the fits the review policy picks); the explanation
says how many labels of each kind it holds.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.enums import DecisionKind, RoundState
from backend.models.fits import Fit
from backend.models.label_audit import LabelAudit
from backend.models.review import Decision, Round
from backend.services.review import label_audits
from backend.services.review.verification import HeuristicThresholds
from backend.settings import Settings

SCALES = (0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.25, 1.5, 1.75, 2.0)


@dataclass(frozen=True)
class Evidence:
    """One judged label: its heuristic metrics (records.record_fit's), whether it was wrong, and from where
    ("audit" or "review")."""

    metrics: dict[str, float]
    wrong: bool
    source: str


def scaled(paper: HeuristicThresholds, scale: float) -> HeuristicThresholds:
    """The paper's thresholds loosened (scale > 1) or tightened (< 1): confidence and IoU minimums move their gap to 1
    by `scale`, the distance maximums (metres) are multiplied by it; the low-IoU rule is kept."""
    if not 0 < scale <= 10:
        raise ValueError(f"scale must be in (0, 10], not {scale}")

    def floor(value: float) -> float:
        return min(1.0, max(0.0, 1 - (1 - value) * scale))

    return HeuristicThresholds(
        min_mean_confidence=floor(paper.min_mean_confidence),
        min_keypoint_confidence=floor(paper.min_keypoint_confidence),
        min_mean_iou=floor(paper.min_mean_iou), low_iou=paper.low_iou, max_low_iou_views=paper.max_low_iou_views,
        max_mean_distance_m=paper.max_mean_distance_m * scale,
        max_keypoint_distance_m=paper.max_keypoint_distance_m * scale)


def passes(metrics: dict[str, float], t: HeuristicThresholds) -> bool:
    """Whether a label with these heuristic metrics (services.review.verification.heuristic_verdict's) passes `t`, as
    the heuristic would decide it."""
    return (metrics["mean_confidence"] > t.min_mean_confidence
            and metrics["min_confidence"] >= t.min_keypoint_confidence
            and metrics["mean_iou"] >= t.min_mean_iou and metrics["low_iou_views"] <= t.max_low_iou_views
            and metrics["mean_distance_m"] <= t.max_mean_distance_m
            and metrics["max_distance_m"] <= t.max_keypoint_distance_m)


METRICS = ("mean_confidence", "min_confidence", "mean_iou", "low_iou_views", "mean_distance_m", "max_distance_m")


def _metrics(heuristic: dict[str, Any] | None) -> dict[str, float] | None:
    if not heuristic or any(heuristic.get(k) is None for k in METRICS):
        return None
    return {k: float(heuristic[k]) for k in METRICS}


def evidence(session: Session) -> list[Evidence]:
    """Audited labels and reviewers' decisions on fits from predictions, with the fits' heuristic metrics. Fits from
    the detector (round 0's heuristic, its own thresholds) are not evidence for MVNet's thresholds: the same metric
    means something else there."""
    out: list[Evidence] = []
    audit_decisions: set[int] = set()
    for row, heuristic in session.execute(select(LabelAudit, Fit.heuristic).join(Fit, Fit.id == LabelAudit.fit_id)
                                          .where(LabelAudit.state == "done", Fit.prediction_id.is_not(None))
                                          .order_by(LabelAudit.id)):
        if row.decision_id is not None:
            audit_decisions.add(row.decision_id)
        if row.kind != "audit":  # a gold look judges the reviewer: the label is known right, whatever they said
            continue
        metrics = _metrics(heuristic)
        if metrics is not None:
            out.append(Evidence(metrics, row.verdict == "wrong", "audit"))
    for decision_id, kind, heuristic in session.execute(
            select(Decision.id, Decision.decision, Fit.heuristic).join(Fit, Fit.id == Decision.fit_id)
            .where(Decision.user_id.is_not(None), Decision.by_heuristic.is_(False), Fit.prediction_id.is_not(None))
            .order_by(Decision.id)):
        metrics = _metrics(heuristic)
        if metrics is None or decision_id in audit_decisions:
            continue
        out.append(Evidence(metrics, kind != DecisionKind.accept.value, "review"))
    return out


@dataclass(frozen=True)
class Choice:
    """The thresholds chosen for a round and why (JSON-ready with `to_json`)."""

    thresholds: HeuristicThresholds
    scale: float
    chosen_by: str  # "paper" (defaults) or "target"
    explanation: str
    evidence_labels: int
    evidence_wrong: int
    upper_bound: float | None

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "thresholds": asdict(self.thresholds)}


def choose(items: list[Evidence], paper: HeuristicThresholds, target: float | None, min_audits: int,
           judge_error_rate: float = 0.0) -> Choice:
    """The loosest scale of the paper's thresholds whose accepted evidence (at least `min_audits` labels) has a
    Wilson 95 % upper bound of its wrong share at most `target`; the paper's thresholds without a target, with fewer
    audited heuristic labels than `min_audits`, or when no scale qualifies (the explanation says which)."""

    def at(scale: float) -> tuple[int, int, float | None]:
        chosen = [e for e in items if passes(e.metrics, scaled(paper, scale))]
        wrong = sum(e.wrong for e in chosen)
        interval = label_audits.wilson_interval(wrong, len(chosen))
        return len(chosen), wrong, None if interval is None else label_audits.corrected(interval[1], judge_error_rate)

    n1, k1, u1 = at(1.0)
    if target is None:
        return Choice(paper, 1.0, "paper", "no precision target set: the paper's thresholds.", n1, k1, u1)
    audits = sum(e.source == "audit" for e in items)
    if audits < min_audits:
        return Choice(paper, 1.0, "paper", f"the paper's thresholds until {min_audits} labels are audited: "
                      f"{audits} audited so far (target: at most {target:.1%} of auto-accepted labels wrong).",
                      n1, k1, u1)
    best = None
    for scale in SCALES:
        n, k, upper = at(scale)
        if n >= min_audits and upper is not None and upper <= target:
            best = (scale, n, k, upper)
    if best is None:
        bound = "no labels" if u1 is None else f"{k1} of {n1} wrong, upper bound {u1:.1%}"
        return Choice(paper, 1.0, "paper", f"no thresholds from {SCALES[0]}x to {SCALES[-1]}x the paper's meet the "
                      f"target of {target:.1%} with the 95 % upper bound on {min_audits}+ judged labels (at the "
                      f"paper's: {bound}); the paper's thresholds stay.", n1, k1, u1)
    scale, n, k, upper = best
    sources = f"{audits} audited, {len(items) - audits} reviewed"
    return Choice(scaled(paper, scale), scale, "target",
                  f"{scale}x the paper's thresholds, the loosest that meets the target: of the {n} judged labels they "
                  f"accept ({sources} in all), {k} wrong, Wilson 95 % upper bound {upper:.1%} <= {target:.1%}.",
                  n, k, upper)


def choose_for_round(session: Session, round_: Round, paper: HeuristicThresholds) -> Choice:
    """Choose the thresholds for `round_` (at its launch) and store them on it, with the explanation."""
    config = label_audits.read_config(session)
    choice = choose(evidence(session), paper, config.precision_target, config.min_audits_for_target,
                    config.auditor_error_rate)
    round_.heuristic_thresholds = choice.to_json()
    return choice


def thresholds_in_force(session: Session, settings: Settings) -> HeuristicThresholds:
    """The open round's chosen thresholds, else the paper's (from the settings): what the heuristic applies now."""
    stored = session.execute(select(Round.heuristic_thresholds).where(Round.state == RoundState.running)
                             .order_by(Round.index.desc()).limit(1)).scalar_one_or_none()
    if stored and stored.get("thresholds"):
        return HeuristicThresholds(**stored["thresholds"])
    return HeuristicThresholds.from_settings(settings)


def current(session: Session) -> dict[str, Any] | None:
    """The newest round's choice (for the admin page), or None before any round chose."""
    row = session.execute(select(Round.index, Round.heuristic_thresholds).where(Round.heuristic_thresholds.is_not(None))
                          .order_by(Round.index.desc()).limit(1)).first()
    return None if row is None else {"round": row[0], **row[1]}

