"""A round's progress, phase by phase: train HandSegNet -> train MVNet -> predict -> fit -> heuristic and
review queue.

Each phase weighs what it is expected to take: a network's training its time budget until it shows its own
pace (training stops at the budget or at a step cap, whichever comes first), then the time its progress says it
takes, and once done the time it took: a step-capped network that trains 2 minutes of a 2-hour budget must not
make the bar read 100 % while prediction and fitting still run (issue 38 item 9). Prediction and fitting weigh
their sample count times the per-sample cost the benchmarks measured, the last step a few seconds. The round
job's progress is the weighted share done, recomputed from the rows of its train, predict and fit jobs whenever
one of them reports (so two networks training at once on two workers do not overwrite each other's share), and
its message names the phase(s) running. The phases are also kept in the round job's result (`phases`), for the
admin page's steps.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.models.enums import JobKind, JobState
from backend.models.jobs import Job
from backend.services.errors import DomainError
from backend.services.jobs import jobs
from backend.settings import Settings

# Expected seconds per sample, from the benchmarks (docs/benchmarks.md): MVNet + HandSegNet inference on an
# 8-view frame 124-460 ms (`bench nets`), a fit from predictions 0.25-0.8 s (`bench jobs`).
PREDICT_S_PER_SAMPLE = 0.3
FIT_S_PER_SAMPLE = 0.6
FINISH_S = 5.0  # heuristic summary, review queue, counts: a few queries
NET_LABELS = {"handsegnet": "HandSegNet", "mvnet": "MVNet"}
LOSS_SEPARATOR = "; loss "


@dataclass(frozen=True)
class Phase:
    """One phase: `weight_s` expected seconds, `done` in [0, 1], `detail` what it has done so far."""

    name: str
    weight_s: float
    done: float
    detail: str = ""

    @property
    def state(self) -> str:
        return "done" if self.done >= 1.0 else ("running" if self.done > 0 else "pending")

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "state": self.state, "done": round(self.done, 4), "detail": self.detail}


def _fraction(job: Job) -> float:
    if job.state == JobState.succeeded:
        return 1.0
    if JobState(job.state) in jobs.FINAL_STATES:
        return 1.0  # failed or cancelled: nothing more will happen in this phase for it
    return min(1.0, max(0.0, float(job.progress or 0.0)))


# A running network's own pace is trusted once it has done this share of its work (before, its budget stands).
PACE_AFTER = 0.02


def train_weight_s(job: Job, budget_s: float, now: datetime, last_took_s: float | None = None) -> float:
    """Seconds a train phase weighs: what it took once over, the time its progress so far says it takes while it
    runs (at most the budget), else what the same network's last training took (`last_took_s`) or its budget."""
    if job.started_at is None:
        return max(1.0, min(budget_s, last_took_s)) if last_took_s else budget_s
    if JobState(job.state) in jobs.FINAL_STATES and job.finished_at is not None:
        return max(1.0, min(budget_s, (job.finished_at - job.started_at).total_seconds()))
    progress = float(job.progress or 0.0)
    if progress < PACE_AFTER:
        return budget_s
    return max(1.0, min(budget_s, (now - job.started_at).total_seconds() / progress))


def train_message(net: str, step: int, seconds: float, budget_s: float, min_steps: int | None, loss: float) -> str:
    """A train job's progress message. Its part before the loss is the round's phase detail (train_detail): the
    steps and seconds the job counted itself, since with a step floor or cap its progress is not seconds over the
    budget."""
    floor = f", at least {min_steps} steps" if min_steps else ""
    return f"training {net}: step {step}, {seconds:.0f} of {budget_s:.0f} s{floor}{LOSS_SEPARATOR}{loss:.4f}"


def train_detail(job: Job, net: str, budget_s: float) -> str:
    """What a train phase shows: 'done', the final state, the job's own steps and seconds (train_message), or
    before it reports them (building its data set) the share done times the budget."""
    done = _fraction(job)
    if job.state == JobState.succeeded:
        return "done"
    if done >= 1:
        return str(job.state)
    prefix, message = f"training {net}: ", job.message or ""
    if message.startswith(prefix) and LOSS_SEPARATOR in message:
        return message[len(prefix):message.rindex(LOSS_SEPARATOR)]
    return f"{done * budget_s:.0f} of {budget_s:.0f} s"


def _last_training_s(session: Session, round_id: int | None) -> dict[str, float]:
    """Per network, the seconds its newest finished training of an earlier round took (the estimate of a
    training not started yet)."""
    rows = session.execute(select(Job.payload, Job.started_at, Job.finished_at)
                           .where(Job.kind == JobKind.train, Job.state == JobState.succeeded,
                                  Job.round_id != round_id, Job.started_at.is_not(None),
                                  Job.finished_at.is_not(None))
                           .order_by(Job.id.desc()).limit(20)).all()
    took: dict[str, float] = {}
    for payload, started, finished in rows:
        took.setdefault(str((payload or {}).get("net")), (finished - started).total_seconds())
    return took


def phases(session: Session, round_job: Job, settings: Settings, now: datetime | None = None) -> list[Phase]:
    """The round's phases at `now` (default: the clock), from its jobs' rows and its result (`candidates`: the
    samples it predicts, known once the predict jobs exist; before, start_round's `candidates_estimate`)."""
    now = now or utcnow()
    round_jobs = session.execute(select(Job).where(Job.round_id == round_job.round_id,
                                                   Job.kind.in_([JobKind.train, JobKind.predict, JobKind.fit]))
                                 ).scalars().all()
    by_kind: dict[str, list[Job]] = {}
    for job in round_jobs:
        by_kind.setdefault(str(job.kind), []).append(job)
    out: list[Phase] = []
    budgets = {"handsegnet": settings.round_handsegnet_budget_s, "mvnet": settings.round_mvnet_budget_s}
    trains = {(j.payload or {}).get("net"): j for j in by_kind.get(JobKind.train.value, [])}
    last_took = _last_training_s(session, round_job.round_id) if any(
        j.started_at is None for j in trains.values()) else {}
    for net, budget in budgets.items():
        job = trains.get(net)
        if job is None:
            continue  # launched with an existing model (or not started yet): nothing to train
        out.append(Phase(f"train {NET_LABELS[net]}", train_weight_s(job, budget, now, last_took.get(net)),
                         _fraction(job),
                         train_detail(job, net, budget)))
    result = round_job.result or {}
    predicts = by_kind.get(JobKind.predict.value, [])
    candidates = max(int(result.get("candidates", result.get("candidates_estimate", 1))), 1)
    sizes = {j.id: len((j.payload or {}).get("sample_ids") or []) for j in predicts}
    predicted = sum(_fraction(j) * sizes[j.id] for j in predicts)
    out.append(Phase("predict", candidates * PREDICT_S_PER_SAMPLE, min(1.0, predicted / candidates),
                     f"{predicted:.0f} of {candidates} samples"))
    fits = by_kind.get(JobKind.fit.value, [])
    all_predicted = bool(predicts) and all(JobState(j.state) in jobs.FINAL_STATES for j in predicts)
    expected = len(fits) if all_predicted else max(len(fits), candidates)
    fitted = sum(_fraction(j) for j in fits)
    out.append(Phase("fit", candidates * FIT_S_PER_SAMPLE, fitted / expected if expected else float(all_predicted),
                     f"{fitted:.0f} of {expected} samples"))
    finish = 0.5 * ("heuristic" in result) + 0.5 * ("review_queue" in result)
    out.append(Phase("heuristic and review queue", FINISH_S, finish, "done" if finish >= 1 else ""))
    return out


def overall(steps: list[Phase]) -> float:
    """The weighted share done, in [0, 1]."""
    total = sum(p.weight_s for p in steps)
    return min(1.0, sum(p.weight_s * p.done for p in steps) / total) if total > 0 else 0.0


def describe(steps: list[Phase], round_index: int | None) -> str:
    """'round 1: train MVNet (120 of 240 s), phase 2 of 5': the phases running (or the next one)."""
    running = [p for p in steps if p.state == "running"] or [p for p in steps if p.state == "pending"][:1]
    where = " + ".join(f"{p.name} ({p.detail})" if p.detail else p.name for p in running) or "finishing"
    number = steps.index(running[0]) + 1 if running else len(steps)
    head = f"round {round_index}: " if round_index is not None else ""
    return f"{head}{where}, phase {number} of {len(steps)}"


def lock(session: Session, round_job_id: int) -> Job | None:
    """The round job's row, locked for this transaction. Train and predict jobs on several workers refresh the
    same row (its result is read, then written); a reporter takes this lock before writing its own jobs, so
    every transaction locks the round before a child (services.jobs.round_failure, from a failed child, locks the
    other train jobs after the round: the other order would deadlock). Pending changes are flushed first (the
    sessions do not autoflush): re-reading the row must not drop what the caller just merged into its result."""
    session.flush()
    return session.execute(select(Job).where(Job.id == round_job_id).with_for_update()
                           .execution_options(populate_existing=True)).scalar_one_or_none()


def refresh(session: Session, round_job_id: int, settings: Settings) -> float | None:
    """Recompute and write the round job's progress, message and phases; the progress, or None when the job
    is gone or over (then nothing is written)."""
    round_job = lock(session, round_job_id)
    if round_job is None or JobState(round_job.state) in jobs.FINAL_STATES or round_job.round_id is None:
        return None
    steps = phases(session, round_job, settings)
    fraction = overall(steps)
    index = (round_job.result or {}).get("round_index")
    with contextlib.suppress(DomainError):  # cancelled meanwhile
        jobs.update_progress(session, round_job_id, fraction, describe(steps, index)[:500])
        round_job.result = {**(round_job.result or {}), "phases": [p.to_dict() for p in steps]}
        return fraction
    return None
