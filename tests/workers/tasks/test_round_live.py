"""A bootstrap round end to end through Celery on a tiny synthetic capture: D_0 annotated and accepted
through the API, then a round launched by the admin runs on the worker (train both networks, predict,
fit, heuristic, review queue) and records D_1 = D_0 + the streams, with model versions and checkpoints."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from sqlalchemy import func, select

from tests.support.annotate import annotate_and_accept, queue_for_annotation

pytestmark = pytest.mark.slow


def run_round(stack) -> dict:
    queue_for_annotation(stack, 3)
    accepted = annotate_and_accept(stack, 3)
    assert len(accepted) == 3
    with stack.client("admin") as http:
        launched = http.post("/api/admin/rounds", json={"note": "test round"})
        assert launched.status_code == 201, launched.text
        job_id = launched.json()["job_id"]
    job = stack.wait_for_job(job_id, timeout_s=600)
    assert job["state"] == "succeeded", job
    return job


def check_round(stack, job: dict) -> None:
    from backend.models.enums import JobKind, JobState
    from backend.models.fits import Fit, Prediction
    from backend.models.jobs import Job
    from backend.models.review import Round, RoundMember

    result = job["result"]
    assert result["round_index"] == 1 and result["dataset_before"] == 3
    assert result["mvnet_version"] == "round-001/mvnet" and result["handsegnet_version"] == "round-001/handsegnet"
    for net in ("mvnet", "handsegnet"):
        assert (Path(stack.settings.checkpoints_dir) / "round-001" / f"{net}.pt").is_file()
    with stack.session_factory()() as session:
        round_ = session.execute(select(Round).where(Round.index == 1)).scalar_one()
        assert round_.mvnet_version == "round-001/mvnet"
        jobs = session.execute(select(Job).where(Job.round_id == round_.id)).scalars().all()
        by_kind = {}
        for row in jobs:
            by_kind.setdefault(row.kind, []).append(row)
        assert sorted((j.payload or {}).get("net") for j in by_kind[JobKind.train]) == ["handsegnet", "mvnet"]
        assert all(j.state == JobState.succeeded for j in by_kind[JobKind.train] + by_kind[JobKind.predict])
        predicted_samples = {s for j in by_kind[JobKind.predict] for s in j.payload["sample_ids"]}
        assert len(predicted_samples) == 3  # every sample outside D_0 was a candidate
        predictions = session.execute(select(func.count()).select_from(Prediction)
                                      .where(Prediction.round_id == round_.id)).scalar_one()
        not_localised = sum(j.result["not_localised"] for j in by_kind[JobKind.predict])
        assert predictions + not_localised == 3
        fits = by_kind.get(JobKind.fit, [])
        assert len(fits) == predictions  # one fit job per prediction of a refittable sample
        assert all(j.state in (JobState.succeeded, JobState.failed) for j in fits)
        # Exactly one fit per succeeded fit job, no duplicates.
        for j in fits:
            n = session.execute(select(func.count()).select_from(Fit).where(Fit.job_id == j.id)).scalar_one()
            assert n == (1 if j.state == JobState.succeeded else 0)
        members = dict(session.execute(select(RoundMember.stream, func.count()).where(RoundMember.round_id == round_.id)
                                       .group_by(RoundMember.stream)).all())
    assert result["added"]["heuristic"] == members.get("heuristic", 0)
    with stack.client("admin") as http:
        stats = http.get("/api/admin/rounds/statistics").json()
    sizes = {r["index"]: r for r in stats["rounds"]}
    assert sizes[0]["added"]["annotated"] == 3 and sizes[0]["dataset_size_after"] == 3
    assert sizes[1]["dataset_size_after"] == 3 + sizes[1]["added_total"]  # D_1 = D_0 + D^h + D^m + D^l


def test_round_runs_end_to_end_on_the_embedded_worker(live_stack):
    """No server at all: SQLite, local files, kombu's filesystem broker, a real worker process."""
    stack = live_stack(frames=6, queue_for_annotation=False)
    assert stack.settings.broker_url is None
    check_round(stack, run_round(stack))


@pytest.mark.redis
@pytest.mark.postgres
def test_round_runs_end_to_end_in_distributed_mode(live_stack):
    """PostgreSQL and the Redis broker: the distributed configuration, on one machine."""
    stack = live_stack(frames=6, queue_for_annotation=False, broker="redis", database="postgres")
    assert stack.settings.broker_url.startswith("redis://")
    assert stack.settings.resolved_database_url.startswith("postgresql")
    check_round(stack, run_round(stack))


def test_a_round_cancelled_while_training_stops_its_jobs(live_stack):
    from backend.models.enums import JobKind
    from backend.models.jobs import Job
    from tests.support.annotate import wait_until

    stack = live_stack(frames=4, queue_for_annotation=False, round_handsegnet_budget_s=300.0,
                       round_mvnet_budget_s=300.0)
    queue_for_annotation(stack, 2)
    annotate_and_accept(stack, 2)
    with stack.client("admin") as http:
        launched = http.post("/api/admin/rounds", json={"note": "to cancel"}).json()

    def training():
        with stack.session_factory()() as session:
            rows = session.execute(select(Job).where(Job.kind == JobKind.train, Job.state == "running")).scalars()
            return [j for j in rows if j.progress > 0]

    wait_until(training, 120, "training under way", stack)
    with stack.session_factory()() as session:  # the round shows the train job's own steps and seconds
        message = session.get(Job, launched["job_id"]).message
    assert re.search(r"train (HandSegNet|MVNet) \(step \d+, \d+ of 300 s", message), message
    with stack.client("admin") as http:
        cancelled = http.post(f"/api/admin/rounds/{launched['round']['id']}/cancel")
        assert cancelled.status_code == 200 and cancelled.json()["state"] == "cancelled", cancelled.text
    job = stack.wait_for_job(launched["job_id"], timeout_s=30)
    assert job["state"] == "cancelled"

    def stopped():
        log = stack.stack.worker_log.read_text()
        return "'cancelled': True" in log

    wait_until(stopped, 30, "the training task returned", stack)  # well before its 300 s budget
    with stack.session_factory()() as session:
        rows = session.execute(select(Job).where(Job.round_id == launched["round"]["id"])).scalars()
        kinds = {row.kind: row.state for row in rows}
    assert kinds.get(JobKind.train) == "cancelled" and JobKind.predict not in kinds
