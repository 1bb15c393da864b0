"""Blind audits of accepted labels (issue 40): how often are D^h, D^m and D^l wrong, measured, per round.

Not the audit trail (services/audit.py records every change): an audit here is a second look at an accepted label.

- Which labels: when a stream accepts a label (the heuristic in the round job, a reviewer in review), it is picked
  for an audit with probability `audit_share` (the admin's setting): a hash of the setting's seed and the
  sample's and fit's ids, so a run repeats and nobody can predict which labels are picked without the seed.
- Blind: the audit is handed out through the reviewers' own queue (`POST /api/review/next` and the prefetch),
  leased in the sample's row as any review task, interleaved with the fitted samples awaiting review. The task
  says 'in_review' and the review page shows no heuristic verdict on any task, so neither that the label was
  accepted nor by whom (nor by the heuristic) shows; a reviewer never audits a label they accepted themselves.
- Verdict: the reviewer's decision on the usual route. Accept: the label was right ('correct'). Reject or
  needs-annotation: 'wrong': the label leaves the dataset (its round member is deleted, so exports and the round's
  figures lose it) with the reviewer's reason, and the sample is rejected or goes back to the annotators as a
  review would send it. The audit row keeps the label's round and stream, so the figures still count it.
- Figures (`summary`): per round and stream, audited, found wrong, that share and its Wilson 95 % interval.
"""

from __future__ import annotations

import hashlib
import math
import secrets
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import and_, delete, func, or_, select
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.capture import Sample
from backend.models.enums import DecisionKind, LeaseKind, RoundState, SampleState, Stream
from backend.models.fits import Fit
from backend.models.label_audit import GoldLabel, LabelAudit, QualitySettings
from backend.models.review import Decision, Round, RoundMember
from backend.services import audit
from backend.services.accounts.users import Actor
from backend.services.captures.state_machine import transition
from backend.services.errors import ConflictError, InvalidInputError, NotFoundError
from backend.services.leases import drafts, queues

Z_95 = 1.959963984540054  # two-sided 95 % normal quantile
MAX_HELD = 2  # review leases a reviewer holds at most (the one on screen and the prefetched: services.leases.prefetch)


@dataclass(frozen=True)
class QualityConfig:
    """The admin's quality settings.

    Attributes:
        audit_share: share of each stream's accepts audited, in [0, 1].
        audit_seed: picks which labels the share takes (with their ids).
        precision_target: at most this share of auto-accepted (D^h) labels wrong, in (0, 1); None: the paper's
            fixed thresholds (services.review.precision_target).
        min_audits_for_target: audited heuristic labels needed before thresholds are chosen from them.
        auditor_error_rate: how often an auditor's verdict is itself wrong (either way), in [0, 0.5): the figures'
            `error_rate_corrected` undo it (a 2 % auditor error alone doubles a 2 % error rate: docs/evaluation.md).
        gold_share: share of a reviewer's tasks that are gold labels (`GoldLabel`) they have not judged yet, [0, 1].
        agreement_share: share of annotated samples a second annotator annotates blind (services.review.agreement),
            [0, 1]; 5 %: a per-person mean over ~20 pairs after ~400 annotated samples, for 5 % more clicking.
    """

    audit_share: float = 0.05
    audit_seed: int = 0
    precision_target: float | None = None
    min_audits_for_target: int = 30
    auditor_error_rate: float = 0.0
    gold_share: float = 0.0
    agreement_share: float = 0.05

    def __post_init__(self) -> None:
        if not (math.isfinite(self.audit_share) and 0 <= self.audit_share <= 1):
            raise InvalidInputError(f"audit_share must be in [0, 1], not {self.audit_share}")
        if self.precision_target is not None and not (math.isfinite(self.precision_target)
                                                      and 0 < self.precision_target < 1):
            raise InvalidInputError(f"precision_target must be in (0, 1) or null, not {self.precision_target}")
        if not 1 <= self.min_audits_for_target <= 1_000_000:
            raise InvalidInputError(f"min_audits_for_target must be in 1..1000000, not {self.min_audits_for_target}")
        if not (math.isfinite(self.auditor_error_rate) and 0 <= self.auditor_error_rate < 0.5):
            raise InvalidInputError(f"auditor_error_rate must be in [0, 0.5), not {self.auditor_error_rate}")
        if not (math.isfinite(self.gold_share) and 0 <= self.gold_share <= 1):
            raise InvalidInputError(f"gold_share must be in [0, 1], not {self.gold_share}")
        if not (math.isfinite(self.agreement_share) and 0 <= self.agreement_share <= 1):
            raise InvalidInputError(f"agreement_share must be in [0, 1], not {self.agreement_share}")
        if not 0 <= self.audit_seed < 2**31:
            raise InvalidInputError(f"audit_seed must be in 0..2147483647, not {self.audit_seed}")


FIELDS = ("audit_share", "audit_seed", "precision_target", "min_audits_for_target", "auditor_error_rate", "gold_share",
          "agreement_share")


def read_config(session: Session) -> QualityConfig:
    """The saved settings, or the defaults before the first change."""
    row = session.get(QualitySettings, 1)
    return QualityConfig() if row is None else QualityConfig(**{k: getattr(row, k) for k in FIELDS})


def update_config(session: Session, actor_id: int | None, changes: dict[str, Any]) -> QualityConfig:
    """Apply `changes` (a subset of FIELDS); InvalidInputError naming the field, nothing written, when out of range."""
    unknown = set(changes) - set(FIELDS)
    if unknown:
        raise InvalidInputError(f"unknown quality settings {sorted(unknown)}; known: {list(FIELDS)}")
    config = replace(read_config(session), **changes)  # validates
    row = session.get(QualitySettings, 1, with_for_update=True)
    if row is None:
        row = QualitySettings(id=1)
        session.add(row)
    for key in FIELDS:
        setattr(row, key, getattr(config, key))
    row.updated_by_id = actor_id
    audit.record(session, actor_id, "quality.settings", "quality_settings", 1, **changes)
    return config


# --- picking and scheduling ------------------------------------------------------------------------------------
def unit_hash(seed: int, *ids: int | str) -> float:
    """A uniform number in [0, 1) from the seed and ids (SHA-256): the same ids and seed, the same number."""
    digest = hashlib.sha256(":".join(str(x) for x in (seed, *ids)).encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2**64


def picked(config: QualityConfig, sample_id: int, fit_id: int | None) -> bool:
    """Whether the label (sample, fit) is audited: with probability `audit_share`, independently per label."""
    return unit_hash(config.audit_seed, "audit", sample_id, fit_id or 0) < config.audit_share


def schedule(session: Session, round_: Round, sample_id: int, fit_id: int | None, stream: Stream,
             accepted_by_id: int | None) -> LabelAudit | None:
    """Called where a stream accepts a label (workers.tasks.records, services.review.review): an audit of it when it is
    picked (`picked`), else None."""
    config = read_config(session)
    if config.audit_share <= 0 or not picked(config, sample_id, fit_id):
        return None
    row = LabelAudit(sample_id=sample_id, fit_id=fit_id, round_id=round_.id, stream=stream.value,
                     accepted_by_id=accepted_by_id, state="pending", reason="")
    session.add(row)
    session.flush()
    audit.record(session, None, "label_audit.schedule", "sample", sample_id, label_audit_id=row.id,
                 stream=stream.value)
    return row


# --- leasing: through the reviewers' queue ------------------------------------------------------------------------
def _live_review(user: Actor, now: datetime):
    return and_(Sample.leased_by_id == user.id, Sample.lease_kind == LeaseKind.review.value,
                Sample.lease_expires_at > now)


def _pending_of(sample_id_col):
    return select(LabelAudit.id).where(LabelAudit.sample_id == sample_id_col, LabelAudit.state == "pending") \
        .exists()


def open_audit(session: Session, sample_id: int, user_id: int | None = None) -> LabelAudit | None:
    """The sample's pending audit (with `user_id`: an audit, or that reviewer's gold look), if any."""
    query = select(LabelAudit).where(LabelAudit.sample_id == sample_id, LabelAudit.state == "pending")
    if user_id is not None:
        query = query.where(or_(LabelAudit.kind == "audit", LabelAudit.auditor_id == user_id))
    return session.execute(query.order_by(LabelAudit.id).limit(1)).scalar_one_or_none()


def _lease(sample: Sample, expires: datetime) -> queues.Lease:
    head = queues.SampleHead(sample.id, sample.sequence_id, sample.frame_index, sample.time_s,
                             SampleState.in_review.value, sample.current_fit_id)  # blind: shown as in review
    return queues.Lease(sample.id, sample.lease_token or "", expires, LeaseKind.review, head)


def _own_audit(session: Session, user: Actor, now: datetime, expires: datetime,
               exclude_sample_id: int | None) -> queues.Lease | None:
    query = select(Sample).where(_live_review(user, now), Sample.state == SampleState.accepted,
                                 _pending_of(Sample.id)).order_by(Sample.id).limit(1).with_for_update()
    if exclude_sample_id is not None:
        query = query.where(Sample.id != exclude_sample_id)
    sample = session.execute(query).scalar_one_or_none()
    if sample is None:
        return None
    sample.lease_expires_at = expires
    return _lease(sample, expires)


def _lapsed_audit(session: Session, user: Actor, now: datetime, expires: datetime,
                  exclude_sample_id: int | None) -> queues.Lease | None:
    """An audit whose lease this reviewer let lapse and nobody took since: theirs again first (with the same token),
    as the queue gives back a sample they left a draft on, so the look on their screen can still be decided."""
    query = (select(Sample).where(Sample.leased_by_id == user.id, Sample.lease_kind == LeaseKind.review.value,
                                  Sample.lease_expires_at <= now, Sample.state == SampleState.accepted,
                                  _open_to(user, Sample.id))
             .order_by(Sample.id).limit(1).with_for_update(skip_locked=True))
    if exclude_sample_id is not None:
        query = query.where(Sample.id != exclude_sample_id)
    sample = session.execute(query).scalar_one_or_none()
    if sample is None:
        return None
    sample.lease_expires_at = expires
    if sample.lease_token is None:
        sample.lease_token = secrets.token_urlsafe(16)
    audit.record(session, user.id, "lease.retake", "sample", sample.id, kind=LeaseKind.review.value, same_token=True)
    return _lease(sample, expires)


def _open_to(user: Actor, sample_id_col):
    """The sample has a pending look this reviewer may decide: an audit of a label they did not accept, or their own
    gold look."""
    return select(LabelAudit.id).where(
        LabelAudit.sample_id == sample_id_col, LabelAudit.state == "pending",
        or_(and_(LabelAudit.kind == "audit",
                 or_(LabelAudit.accepted_by_id.is_(None), LabelAudit.accepted_by_id != user.id)),
            and_(LabelAudit.kind == "gold", LabelAudit.auditor_id == user.id))).exists()


def retake(session: Session, user: Actor, sample_id: int, token: str | None, lease_seconds: int,
           now: datetime | None = None) -> queues.Lease:
    """The review queue's retake (services.leases.queues.retake) for audits too: an accepted sample whose pending look
    this reviewer may decide is the review queue's work, so a lapsed audit lease is taken again like any other.
    ConflictError naming what to do when the look was decided or withdrawn meanwhile (blind: not the sample's state)."""
    sample = queues.load_locked(session, sample_id)
    if sample.state != SampleState.accepted:
        return queues.retake(session, user, sample_id, LeaseKind.review, token, lease_seconds, now)
    open_to_user = session.execute(select(_open_to(user, sample_id))).scalar()
    if not open_to_user:
        raise ConflictError(f"sample {sample_id} was decided or withdrawn while your review lease had lapsed; ask "
                            "for the next task")
    return queues.retake(session, user, sample_id, LeaseKind.review, token, lease_seconds, now, in_queue=True)


def _free_audit(session: Session, user: Actor, now: datetime, exclude_sample_id: int | None) -> LabelAudit | None:
    """The oldest pending audit a reviewer may take: its sample free, not a label this reviewer accepted."""
    query = (select(LabelAudit).join(Sample, Sample.id == LabelAudit.sample_id)
             .where(LabelAudit.state == "pending", LabelAudit.kind == "audit", Sample.state == SampleState.accepted,
                    or_(LabelAudit.accepted_by_id.is_(None), LabelAudit.accepted_by_id != user.id),
                    or_(Sample.lease_expires_at.is_(None), Sample.lease_expires_at <= now))
             .order_by(LabelAudit.id).limit(1).with_for_update(skip_locked=True, of=Sample))
    if exclude_sample_id is not None:
        query = query.where(LabelAudit.sample_id != exclude_sample_id)
    return session.execute(query).scalar_one_or_none()


def _take(session: Session, user: Actor, row: LabelAudit, now: datetime, expires: datetime,
          action: str) -> queues.Lease:
    sample = queues.load_locked(session, row.sample_id)
    sample.leased_by_id = user.id
    sample.lease_kind = LeaseKind.review.value
    sample.lease_token = secrets.token_urlsafe(16)
    sample.lease_expires_at = expires
    audit.record(session, user.id, action, "sample", sample.id, kind=LeaseKind.review.value)
    return _lease(sample, expires)


def _gold_due(session: Session, user: Actor, config: QualityConfig, now: datetime,
              exclude_sample_id: int | None, *, always: bool = False) -> LabelAudit | None:
    """A gold look for this reviewer, when the coin (seed, reviewer, their looks so far) says so or `always` (their
    queue is empty otherwise): a gold label they have not judged (nor accepted, nor audited), its sample free; the
    pending row, already theirs. None with gold_share 0."""
    if config.gold_share <= 0:
        return None
    if not always:
        looks = session.execute(select(func.count()).select_from(Decision)
                                .where(Decision.user_id == user.id)).scalar_one()
        if unit_hash(config.audit_seed, "gold", user.id, looks) >= config.gold_share:
            return None
    judged = select(LabelAudit.id).where(LabelAudit.kind == "gold", LabelAudit.auditor_id == user.id,
                                         LabelAudit.sample_id == GoldLabel.sample_id,
                                         LabelAudit.fit_id == GoldLabel.fit_id).exists()
    own_accept = select(Decision.id).where(Decision.sample_id == GoldLabel.sample_id,
                                           Decision.fit_id == GoldLabel.fit_id, Decision.user_id == user.id).exists()
    query = (select(GoldLabel).join(Sample, Sample.id == GoldLabel.sample_id)
             .where(Sample.state == SampleState.accepted, Sample.current_fit_id == GoldLabel.fit_id, ~judged,
                    ~own_accept, or_(Sample.lease_expires_at.is_(None), Sample.lease_expires_at <= now))
             .order_by(GoldLabel.id).limit(1).with_for_update(skip_locked=True, of=Sample))
    if exclude_sample_id is not None:
        query = query.where(GoldLabel.sample_id != exclude_sample_id)
    gold = session.execute(query).scalar_one_or_none()
    if gold is None:
        return None
    row = LabelAudit(sample_id=gold.sample_id, fit_id=gold.fit_id, round_id=None, stream=gold.stream, kind="gold",
                     accepted_by_id=None, auditor_id=user.id, state="pending", reason="")
    session.add(row)
    session.flush()
    return row


def mark_gold(session: Session, actor_id: int, sample_id: int) -> GoldLabel:
    """Mark the accepted label of `sample_id` gold (NotFoundError for a sample not in the dataset; marking it again
    changes nothing)."""
    member = session.execute(select(RoundMember).where(RoundMember.sample_id == sample_id)).scalar_one_or_none()
    if member is None or member.fit_id is None:
        raise NotFoundError(f"sample {sample_id} has no accepted label to mark gold; accept it first")
    gold = session.execute(select(GoldLabel).where(GoldLabel.sample_id == sample_id)).scalar_one_or_none()
    if gold is None:
        gold = GoldLabel(sample_id=sample_id, fit_id=member.fit_id, stream=member.stream, marked_by_id=actor_id)
        session.add(gold)
        session.flush()
        audit.record(session, actor_id, "gold.mark", "sample", sample_id, fit_id=member.fit_id)
    return gold


def gold_decision_ids(session: Session) -> set[int]:
    """The decisions that were looks at gold labels (not judgements of anyone's work)."""
    return set(session.execute(select(LabelAudit.decision_id).where(LabelAudit.kind == "gold",
                                                                   LabelAudit.decision_id.is_not(None))).scalars())


def gold_agreement(session: Session) -> list[dict[str, Any]]:
    """Per reviewer: gold labels judged, agreed with (accepted), the share and its Wilson 95 % interval."""
    from_rows = session.execute(select(LabelAudit.auditor_id, LabelAudit.verdict, func.count())
                                .where(LabelAudit.kind == "gold", LabelAudit.state == "done")
                                .group_by(LabelAudit.auditor_id, LabelAudit.verdict)).all()
    per: dict[int, list[int]] = {}
    for user_id, verdict, n in from_rows:
        cell = per.setdefault(int(user_id), [0, 0])
        cell[0] += int(n)
        cell[1] += int(n) if verdict == "correct" else 0
    out = []
    for user_id, (judged, agreed) in sorted(per.items()):
        interval = wilson_interval(agreed, judged)
        out.append({"user_id": user_id, "gold_judged": judged, "gold_agreed": agreed,
                    "agreement": agreed / judged if judged else None,
                    "agreement_ci95": None if interval is None else [round(interval[0], 6), round(interval[1], 6)]})
    return out


def _held_regular(session: Session, user: Actor, now: datetime, exclude_sample_id: int | None) -> int:
    query = select(func.count()).select_from(Sample).where(_live_review(user, now),
                                                           Sample.state == SampleState.in_review)
    if exclude_sample_id is not None:
        query = query.where(Sample.id != exclude_sample_id)
    return session.execute(query).scalar_one()


def next_review(session: Session, user: Actor, lease_seconds: int, regular: Callable[[], queues.Lease | None], *,
                ahead_of: int | None = None, now: datetime | None = None) -> tuple[queues.Lease | None, bool]:
    """The reviewer's next task with audits interleaved: (lease, is_audit); (None, False) when both are empty.

    `regular()`: the queue's own lease (services.leases.queues.acquire, or prefetch.acquire_ahead with `ahead_of`, the
    sample on screen). An audit the reviewer holds comes back first (as the queue's own lease does); a regular
    lease they hold next; then a free audit or a free fitted sample, chosen by a coin of the seed and the audit's id
    (half and half while both wait), so an audit's place in the queue does not give it away."""
    now = now or utcnow()
    expires = now + timedelta(seconds=lease_seconds)
    own = _own_audit(session, user, now, expires, ahead_of)
    if own is not None:
        return own, True
    if _held_regular(session, user, now, ahead_of) > 0:
        return regular(), False
    held = session.execute(select(func.count()).select_from(Sample).where(_live_review(user, now))).scalar_one()
    if held >= MAX_HELD:
        return None, False
    lapsed = _lapsed_audit(session, user, now, expires, ahead_of)
    if lapsed is not None:
        return lapsed, True
    action = "lease.acquire" if ahead_of is None else "lease.prefetch"
    config = read_config(session)
    gold = _gold_due(session, user, config, now, ahead_of)
    if gold is not None:
        return _take(session, user, gold, now, expires, action), True
    candidate = _free_audit(session, user, now, ahead_of)
    if candidate is not None:
        waiting = queues.queue_length(session, LeaseKind.review, now)
        if waiting == 0 or unit_hash(config.audit_seed, "serve", candidate.id) < 0.5:
            return _take(session, user, candidate, now, expires, action), True
    lease = regular()
    if lease is None and candidate is not None:
        return _take(session, user, candidate, now, expires, action), True
    if lease is None:  # nothing else waits: a gold label this reviewer has not judged, whatever the coin says
        gold = _gold_due(session, user, config, now, ahead_of, always=True)
        if gold is not None:
            return _take(session, user, gold, now, expires, action), True
    return lease, False


# --- the verdict ------------------------------------------------------------------------------------------------------
def _recount(session: Session, round_id: int | None) -> None:
    """A completed round's stored counts after a label left it (the statistics read the members live)."""
    round_ = session.get(Round, round_id) if round_id is not None else None
    if round_ is None or round_.state != RoundState.completed:
        return
    rows = session.execute(select(RoundMember.stream, func.count()).where(RoundMember.round_id == round_.id)
                           .group_by(RoundMember.stream)).all()
    round_.counts = {str(stream): int(n) for stream, n in rows}


def decide(session: Session, user: Actor, sample: Sample, decision: DecisionKind, reason: str,
           round_: Round) -> tuple[Decision, Sample, Stream | None, bool]:
    """The reviewer's decision on an audit they hold (services.review.review.decide hands it here for an accepted
    sample): the verdict beside the label; a wrong label leaves the dataset (rejected on 'reject', else to the
    annotators: a discard too, since the label was one and is fixed now rather than left to the next round).
    Returns the decision row, the sample, the stream a regular accept would report for an audit (so the page cannot
    tell), and whether it was a gold look.

    A gold look is a test of the reviewer, not of the label (known right): the sample's state and label never move,
    the verdict is the reviewer's answer ('correct': agreed), the stream None (nothing joined the dataset), and the
    answer says so (`recorded_as` 'gold_answer' in the API): the look was blind until decided, and each reviewer sees
    a gold label once, so saying it afterwards gives nothing away for later tasks."""
    row = open_audit(session, sample.id, user.id)
    if row is None:  # blind: the look is over, whatever the sample's state says
        raise ConflictError(f"sample {sample.id} was decided or withdrawn while your review lease had lapsed; ask "
                            "for the next task")
    if row.accepted_by_id is not None and row.accepted_by_id == user.id:
        raise ConflictError(f"sample {sample.id} is not yours to judge; ask for the next task")
    fit = session.get(Fit, row.fit_id) if row.fit_id is not None else None
    shown_stream = Stream.annotated if fit is not None and fit.from_annotation else Stream.manual
    now = utcnow()
    row.auditor_id = user.id
    row.decided_at = now
    row.state = "done"
    row.reason = reason
    if row.kind == "gold":  # a gold label is known right: the verdict is the reviewer's agreement, nothing moves
        row.verdict = "correct" if decision is DecisionKind.accept else "wrong"
        stream: Stream | None = None
    elif decision is DecisionKind.accept:
        row.verdict = "correct"
        stream = shown_stream
    else:
        row.verdict = "wrong"
        stream = None
        removed = session.execute(delete(RoundMember).where(RoundMember.sample_id == sample.id)).rowcount
        _recount(session, row.round_id)
        target = SampleState.rejected if decision is DecisionKind.reject else SampleState.needs_annotation
        transition(session, sample, target, user.id, reason=f"audit {row.id} found the {row.stream} label wrong: "
                                                            f"{reason}")
        audit.record(session, user.id, "label_audit.remove", "sample", sample.id, label_audit_id=row.id,
                     stream=row.stream, round_id=row.round_id, members_removed=removed, reason=reason)
    queues.clear(sample)
    drafts.delete_for_sample(session, sample.id, LeaseKind.review)
    decision_row = Decision(sample_id=sample.id, fit_id=row.fit_id, round_id=round_.id, user_id=user.id,
                            decision=decision, reason=reason)
    session.add(decision_row)
    session.flush()
    row.decision_id = decision_row.id
    audit.record(session, user.id, "label_audit.decide", "sample", sample.id, label_audit_id=row.id,
                 kind=row.kind, verdict=row.verdict, decision=decision.value)
    return decision_row, sample, stream, row.kind == "gold"


# --- the figures ------------------------------------------------------------------------------------------------------
def wilson_interval(wrong: int, n: int, z: float = Z_95) -> tuple[float, float] | None:
    """Wilson score interval of a binomial share `wrong`/`n` (e.g. 95 % with the default z); None for n = 0."""
    if n < 0 or not 0 <= wrong <= n:
        raise ValueError(f"need 0 <= wrong <= n, got wrong={wrong}, n={n}")
    if n == 0:
        return None
    p = wrong / n
    denominator = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def corrected(share: float, auditor_error_rate: float) -> float:
    """The share of labels wrong, from the share the auditors called wrong when each verdict flips with probability
    `auditor_error_rate` e: called = p (1 - e) + (1 - p) e, so p = (called - e) / (1 - 2 e), clipped to [0, 1]."""
    if not 0 <= auditor_error_rate < 0.5:
        raise ValueError(f"auditor_error_rate must be in [0, 0.5), not {auditor_error_rate}")
    return min(1.0, max(0.0, (share - auditor_error_rate) / (1 - 2 * auditor_error_rate)))


def figure(audited: int, wrong: int, pending: int = 0, auditor_error_rate: float = 0.0) -> dict[str, Any]:
    """One cell of the figures: audited, called wrong, that share and its Wilson 95 % interval, and both corrected
    for the auditors' own error rate (`corrected`; the same without one). Shares in [0, 1]."""
    interval = wilson_interval(wrong, audited)
    e = auditor_error_rate
    return {"audited": audited, "wrong": wrong, "pending": pending,
            "error_rate": wrong / audited if audited else None,
            "error_rate_ci95": None if interval is None else [round(interval[0], 6), round(interval[1], 6)],
            "error_rate_corrected": corrected(wrong / audited, e) if audited else None,
            "error_rate_corrected_ci95": None if interval is None else [round(corrected(interval[0], e), 6),
                                                                         round(corrected(interval[1], e), 6)]}


def summary(session: Session) -> dict[str, Any]:
    """Per round and stream, and per stream over all rounds: audited labels, how many were wrong, the share
    and its Wilson 95 % interval, audits still pending; with the settings (`QualityConfig`)."""
    rows = session.execute(
        select(Round.index, LabelAudit.stream, LabelAudit.state, LabelAudit.verdict, func.count())
        .join(Round, Round.id == LabelAudit.round_id, isouter=True)
        .where(LabelAudit.state != "void", LabelAudit.kind == "audit")
        .group_by(Round.index, LabelAudit.stream, LabelAudit.state, LabelAudit.verdict)).all()
    cells: dict[tuple[int | None, str], list[int]] = {}
    for index, stream, state, verdict, n in rows:
        cell = cells.setdefault((index, stream), [0, 0, 0])  # audited, wrong, pending
        if state == "pending":
            cell[2] += int(n)
        else:
            cell[0] += int(n)
            cell[1] += int(n) if verdict == "wrong" else 0
    config = read_config(session)
    e = config.auditor_error_rate
    per_round = [{"round": index, "stream": stream, **figure(*cell, auditor_error_rate=e)}
                 for (index, stream), cell in sorted(cells.items(), key=lambda kv: (kv[0][0] is None, kv[0][0] or 0,
                                                                                    kv[0][1]))]
    streams = {}
    for stream in Stream:
        total = [sum(c[i] for (_, s), c in cells.items() if s == stream.value) for i in range(3)]
        streams[stream.value] = figure(*total, auditor_error_rate=e)
    return {"settings": {k: getattr(config, k) for k in FIELDS}, "rounds": per_round, "streams": streams,
            "gold": gold_agreement(session),
            "method": "each accepted label is audited with probability audit_share; a reviewer judges it blind; "
                      "wrong = rejected or sent back; interval: Wilson score, 95 %; corrected: for the auditors' own "
                      "error rate (auditor_error_rate)"}


def list_audits(session: Session) -> list[dict[str, Any]]:
    """Every audit with its label (sample, fit with its parameters, round index, stream), verdict and reason: what a
    client that knows the truth (the simulation) compares with, including the labels audits took out. Gold looks
    too (`kind` 'gold': the verdict is the reviewer's answer, 'wrong' = they rejected a label known right)."""
    rows = session.execute(select(LabelAudit, Round.index, Fit.params)
                           .join(Round, Round.id == LabelAudit.round_id, isouter=True)
                           .join(Fit, Fit.id == LabelAudit.fit_id, isouter=True).order_by(LabelAudit.id)).all()
    return [{"id": a.id, "kind": a.kind, "sample_id": a.sample_id, "round": index, "stream": a.stream,
             "state": a.state, "verdict": a.verdict, "reason": a.reason,
             # Only an audit takes a label out; a gold look's 'wrong' is the reviewer's miss, the label stays.
             "label_removed": a.kind == "audit" and a.verdict == "wrong",
             "by_heuristic": a.accepted_by_id is None and a.stream == Stream.heuristic.value,
             "fit": None if a.fit_id is None else {"id": a.fit_id, "params": params}}
            for a, index, params in rows]
