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
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

from sqlalchemy import case, func, select
from sqlalchemy.orm import Session

from backend.models.audit import AuditEvent
from backend.models.enums import DecisionKind, Visibility
from backend.models.labels import Click, Submission
from backend.models.review import Decision
from backend.models.users import User
from backend.services.review import label_audits
from backend.services.statistics.activity import ACTION as ACTIVITY


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

    decisions = session.execute(select(Decision.id, Decision.sample_id, Decision.fit_id, Decision.user_id,
                                       Decision.decision, Decision.created_at)
                                .where(Decision.user_id.is_not(None), Decision.by_heuristic.is_(False))
                                .order_by(Decision.created_at, Decision.id)).all()
    by_sample: dict[int, list[Any]] = defaultdict(list)
    for d in decisions:
        by_sample[d.sample_id].append(d)
        rows[d.user_id]["decisions"] += 1
    for s in submissions:  # the first human decision on the sample after the submission judges it
        verdict = next((d for d in by_sample.get(s.sample_id, []) if d.created_at >= s.created_at), None)
        if verdict is not None:
            rows[s.user_id]["decided"] += 1
            rows[s.user_id]["accepted"] += verdict.decision == DecisionKind.accept
    gold_looks = label_audits.gold_decision_ids(session)  # a gold label is known right: no one is overturned by it
    for list_ in by_sample.values():
        for i, d in enumerate(list_):
            later = next((e for e in list_[i + 1:] if e.fit_id == d.fit_id and e.user_id != d.user_id
                          and e.id not in gold_looks), None)
            if d.fit_id is not None and later is not None and later.decision != d.decision:
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
