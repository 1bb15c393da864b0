"""Per-person statistics for the admin page (GET /api/admin/team/statistics): what each annotator and
reviewer did, and how their work fared.

Annotators, from their submissions:
- `samples`: distinct samples submitted; `submissions`;
- `points_placed`: clicks placed by hand (visible or occluded, not accepted from a proposal);
  `proposals_accepted`: points taken from a proposal; not-annotated points are counted in neither;
- `seconds_per_sample`: their submissions' active time (the browser's clock, idle gaps capped) per sample;
- `accept_rate`: of their submissions that a person has decided on since (the next human decision on the
  sample after the submission), the share accepted; None while none is decided.
Reviewers, from their decisions (the heuristic's are nobody's):
- `decisions`, and `seconds_per_decision` from the review page's activity logs (None without a log);
- `overturned`: their decisions on a fit that someone else later decided differently on (the same fit of the
  same sample: a "needs annotation" followed by a new fit is the workflow, not an overturn); a blind audit that
  finds an accept wrong overturns it, a look at a gold label does not (services.review.label_audits);
- `gold_judged`, `gold_agreement`: gold labels slipped into their queue, and the share they accepted (issue 40).

Over time (`quality_over_time`, GET /api/admin/quality `people`): the same figures per person per calendar week
(UTC, from Monday), each person's newest week beside their earlier weeks and the team median, so a person is
compared with themselves and with the team.
"""

from __future__ import annotations

import statistics
from collections import defaultdict
from collections.abc import Hashable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import case, func, select
from sqlalchemy.orm import Session

from backend.models.audit import AuditEvent
from backend.models.enums import DecisionKind, Visibility
from backend.models.label_audit import LabelAudit
from backend.models.labels import Click, Submission
from backend.models.review import Decision
from backend.models.users import User
from backend.services.review import label_audits
from backend.services.statistics.activity import ACTION as ACTIVITY


def _verdict(by_sample: dict[int, list[Any]], submission: Any) -> bool | None:
    """Whether the first human decision on the sample after the submission accepted it; None while none is made."""
    verdict = next((d for d in by_sample.get(submission.sample_id, []) if d.created_at >= submission.created_at), None)
    return None if verdict is None else verdict.decision == DecisionKind.accept


def _overturned(by_sample: dict[int, list[Any]], gold_looks: set[int]) -> list[Any]:
    """The decisions someone else later decided differently on, the same fit of the same sample (a look at a gold
    label overturns nobody: a gold label is known right)."""
    out = []
    for list_ in by_sample.values():
        for i, d in enumerate(list_):
            later = next((e for e in list_[i + 1:] if e.fit_id == d.fit_id and e.user_id != d.user_id
                          and e.id not in gold_looks), None)
            if d.fit_id is not None and later is not None and later.decision != d.decision:
                out.append(d)
    return out


def _human_decisions(session: Session) -> list[Any]:
    """People's decisions (not the heuristic's), oldest first: id, sample_id, fit_id, user_id, decision, created_at."""
    return list(session.execute(select(Decision.id, Decision.sample_id, Decision.fit_id, Decision.user_id,
                                       Decision.decision, Decision.created_at)
                                .where(Decision.user_id.is_not(None), Decision.by_heuristic.is_(False))
                                .order_by(Decision.created_at, Decision.id)).all())


def team_statistics(session: Session) -> list[dict[str, Any]]:
    """One row per user (by id) with the fields of the module docstring (zeros and None where they did
    nothing of a kind)."""
    users = session.execute(select(User.id, User.email, User.full_name, User.role).order_by(User.id)).all()
    rows = {u.id: {"user_id": u.id, "email": u.email, "full_name": u.full_name, "role": u.role, "samples": 0,
                   "submissions": 0, "points_placed": 0, "proposals_accepted": 0, "seconds_per_sample": None,
                   "decided": 0, "accepted": 0, "accept_rate": None, "decisions": 0, "seconds_per_decision": None,
                   "overturned": 0, "gold_judged": 0, "gold_agreement": None} for u in users}
    submissions = session.execute(select(Submission.id, Submission.user_id, Submission.sample_id,
                                         Submission.time_spent_s, Submission.created_at)).all()
    seconds: dict[int, float] = defaultdict(float)
    samples: dict[int, set[int]] = defaultdict(set)
    for s in submissions:
        row = rows[s.user_id]
        row["submissions"] += 1
        seconds[s.user_id] += s.time_spent_s
        samples[s.user_id].add(s.sample_id)
    placed = (Click.visibility != Visibility.not_annotated) & ~Click.from_proposal
    accepted = (Click.visibility != Visibility.not_annotated) & Click.from_proposal
    for user_id, n_placed, n_accepted in session.execute(
            select(Click.user_id, func.sum(case((placed, 1), else_=0)), func.sum(case((accepted, 1), else_=0)))
            .group_by(Click.user_id)):
        if user_id in rows:
            rows[user_id]["points_placed"] = int(n_placed or 0)
            rows[user_id]["proposals_accepted"] = int(n_accepted or 0)
    for user_id, sample_ids in samples.items():
        rows[user_id]["samples"] = len(sample_ids)
        rows[user_id]["seconds_per_sample"] = round(seconds[user_id] / len(sample_ids), 1)

    decisions = _human_decisions(session)
    by_sample: dict[int, list[Any]] = defaultdict(list)
    for d in decisions:
        by_sample[d.sample_id].append(d)
        rows[d.user_id]["decisions"] += 1
    for s in submissions:
        verdict = _verdict(by_sample, s)
        if verdict is not None:
            rows[s.user_id]["decided"] += 1
            rows[s.user_id]["accepted"] += verdict
    for d in _overturned(by_sample, label_audits.gold_decision_ids(session)):
        rows[d.user_id]["overturned"] += 1
    review_seconds: dict[int, list[float]] = defaultdict(list)
    for actor_id, data in session.execute(select(AuditEvent.actor_id, AuditEvent.data)
                                          .where(AuditEvent.action == ACTIVITY, AuditEvent.entity == "decision")):
        spent = ((data or {}).get("summary") or {}).get("time_spent_s")
        if actor_id in rows and isinstance(spent, int | float):
            review_seconds[actor_id].append(float(spent))
    for user_id, spent in review_seconds.items():
        rows[user_id]["seconds_per_decision"] = round(sum(spent) / len(spent), 1)
    for person in label_audits.gold_agreement(session):
        if person["user_id"] in rows:
            rows[person["user_id"]]["gold_judged"] = person["gold_judged"]
            rows[person["user_id"]]["gold_agreement"] = person["agreement"]
    for row in rows.values():
        if row["decided"]:
            row["accept_rate"] = round(row["accepted"] / row["decided"], 3)
    return list(rows.values())


# --- over time ------------------------------------------------------------------------------------------------------
# name -> (who it is about, what it means, digits): the order the page shows them in.
FIGURES: dict[str, tuple[str, str, int]] = {
    "accept_rate": ("annotator", "share of their submissions (made in the week) accepted at the next decision", 3),
    "seconds_per_sample": ("annotator", "active seconds per sample they submitted", 1),
    "overturned_rate": ("reviewer", "share of their decisions someone else later decided differently", 3),
    "gold_agreement": ("reviewer", "share of the gold labels slipped into their queue that they accepted", 3),
    "seconds_per_decision": ("reviewer", "seconds per decision, from the review page's activity logs", 1),
}


@dataclass(frozen=True, slots=True)
class Work:
    """One unit of a figure: a person's `amount` (1/0 for a share, seconds for a time) at `at`, counted once per
    `unit` (a submission, a decision, a sample): the figure of a set is sum(amount) / distinct units."""

    figure: str
    user_id: int
    at: datetime
    amount: float
    unit: Hashable


def _utc(at: datetime) -> datetime:
    return at.replace(tzinfo=UTC) if at.tzinfo is None else at.astimezone(UTC)  # SQLite hands back naive UTC


def week_of(at: datetime) -> datetime:
    """The Monday 00:00 UTC that starts `at`'s week."""
    day = _utc(at).replace(hour=0, minute=0, second=0, microsecond=0)
    return day - timedelta(days=day.weekday())


def work_items(session: Session) -> list[Work]:
    """Every person's work as figure units, with when it was done (the submission, the decision, the gold look)."""
    items: list[Work] = []
    submissions = session.execute(select(Submission.id, Submission.user_id, Submission.sample_id,
                                         Submission.time_spent_s, Submission.created_at)).all()
    decisions = _human_decisions(session)
    by_sample: dict[int, list[Any]] = defaultdict(list)
    for d in decisions:
        by_sample[d.sample_id].append(d)
    for s in submissions:
        # Seconds per sample: a sample submitted twice in a week counts once, its seconds summed.
        items.append(Work("seconds_per_sample", s.user_id, s.created_at, float(s.time_spent_s), s.sample_id))
        verdict = _verdict(by_sample, s)
        if verdict is not None:
            items.append(Work("accept_rate", s.user_id, s.created_at, float(verdict), ("submission", s.id)))
    gold_looks = label_audits.gold_decision_ids(session)
    overturned = {d.id for d in _overturned(by_sample, gold_looks)}
    for d in decisions:
        if d.id not in gold_looks:  # a gold look is the reviewer's answer, counted in gold_agreement
            items.append(Work("overturned_rate", d.user_id, d.created_at, float(d.id in overturned), d.id))
    for audit_id, user_id, verdict, at in session.execute(
            select(LabelAudit.id, LabelAudit.auditor_id, LabelAudit.verdict, LabelAudit.decided_at)
            .where(LabelAudit.kind == "gold", LabelAudit.state == "done", LabelAudit.auditor_id.is_not(None),
                   LabelAudit.decided_at.is_not(None))):
        items.append(Work("gold_agreement", int(user_id), at, float(verdict == "correct"), audit_id))
    for event_id, actor_id, at, data in session.execute(
            select(AuditEvent.id, AuditEvent.actor_id, AuditEvent.at, AuditEvent.data)
            .where(AuditEvent.action == ACTIVITY, AuditEvent.entity == "decision", AuditEvent.actor_id.is_not(None))):
        spent = ((data or {}).get("summary") or {}).get("time_spent_s")
        if isinstance(spent, int | float):
            items.append(Work("seconds_per_decision", int(actor_id), at, float(spent), event_id))
    return items


def _value(items: list[Work], figure: str) -> dict[str, Any]:
    units = {w.unit for w in items}
    value = round(sum(w.amount for w in items) / len(units), FIGURES[figure][2]) if units else None
    return {"value": value, "n": len(units)}


def _median(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return round(statistics.median(present), 4) if present else None


def quality_over_time(session: Session, items: list[Work] | None = None) -> dict[str, Any]:
    """Per person and figure (FIGURES): the value in the current week (the newest week anyone worked), over their
    earlier weeks together, and per week; with the team median of the current and the earlier values (over the
    people with a value). `n`: the units behind a value (submissions, samples, decisions, gold looks)."""
    items = work_items(session) if items is None else items
    users = {u.id: u for u in session.execute(select(User.id, User.email, User.full_name, User.role))}
    current = max((week_of(w.at) for w in items), default=None)
    grouped: dict[tuple[int, str], list[Work]] = defaultdict(list)
    for w in items:
        if w.user_id in users:
            grouped[(w.user_id, w.figure)].append(w)
    people: dict[int, dict[str, Any]] = {}
    for (user_id, figure), work in sorted(grouped.items(), key=lambda kv: kv[0]):
        u = users[user_id]
        person = people.setdefault(user_id, {"user_id": user_id, "email": u.email, "full_name": u.full_name,
                                             "role": u.role, "figures": {}})
        weeks: dict[datetime, list[Work]] = defaultdict(list)
        for w in work:
            weeks[week_of(w.at)].append(w)
        earlier = [w for week, ws in weeks.items() if week < current for w in ws]
        person["figures"][figure] = {
            "current": _value(weeks.get(current, []), figure), "earlier": _value(earlier, figure),
            "weeks": [{"week": week.date().isoformat(), **_value(ws, figure)} for week, ws in sorted(weeks.items())]}
    median = {figure: {"current": _median([p["figures"].get(figure, {}).get("current", {}).get("value")
                                           for p in people.values()]),
                       "earlier": _median([p["figures"].get(figure, {}).get("earlier", {}).get("value")
                                           for p in people.values()])}
              for figure in FIGURES}
    return {"period": "week", "current_week": None if current is None else current.date().isoformat(),
            "figures": [{"name": name, "about": about, "meaning": meaning}
                        for name, (about, meaning, _) in FIGURES.items()],
            "people": list(people.values()), "team_median": median,
            "method": "calendar weeks (UTC, from Monday); current: the newest week anyone worked; earlier: the "
                      "person's weeks before it together; team median: over the people with a value"}
