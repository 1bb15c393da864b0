"""`handloop import` on an empty data folder (SQLite): the database is migrated first, and round 0's
pre-annotation is queued where the detector is installed (`--preannotate/--no-preannotate`); `--wait` follows
the job to its end. The detector is the ground-truth fake (tests/support/detector_fake.py) and the "worker" is
this process, run from the follow's wait: no clock is waited on."""

from __future__ import annotations

import json

import pytest
from sqlalchemy import create_engine, text
from typer.testing import CliRunner

from backend.cli import job_progress
from backend.cli.main import app
from backend.services.rounds import preannotation
from tests.support.live_stack import tiny_capture

MISSING = "the hand landmark model file is missing: install it with scripts/fetch_models.sh"
runner = CliRunner()


@pytest.fixture()
def data_dir(tmp_path, monkeypatch):
    """An empty data folder (no database yet) that the CLI's settings point at; the embedded broker."""
    from backend.settings import get_settings

    for name in ("HANDLOOP_DATABASE_URL", "HANDLOOP_BROKER_URL", "HANDLOOP_PREANNOTATE_ON_IMPORT"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HANDLOOP_DATA_DIR", str(tmp_path / "data"))
    get_settings.cache_clear()
    yield tmp_path / "data"
    get_settings.cache_clear()


@pytest.fixture()
def capture(capture_cache):
    return tiny_capture(capture_cache, frames=4)


def _detector(monkeypatch, problem: str | None) -> None:
    monkeypatch.setattr(preannotation, "quick_detector_problem", lambda: problem)
    monkeypatch.setattr(preannotation, "detector_problem", lambda: problem)


def _rows(data_dir, sql: str) -> list[tuple]:
    engine = create_engine(f"sqlite:///{data_dir / 'handloop.sqlite3'}")
    try:
        with engine.connect() as db:
            return [tuple(r) for r in db.execute(text(sql)).all()]
    finally:
        engine.dispose()


def _states(data_dir) -> dict[str, int]:
    return dict(_rows(data_dir, "SELECT state, count(*) FROM samples GROUP BY state"))


def _imported(result) -> dict:
    assert result.exit_code == 0, result.output[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_import_on_an_empty_data_folder_migrates_and_queues_the_pre_annotation(data_dir, capture, monkeypatch):
    _detector(monkeypatch, None)
    assert not (data_dir / "handloop.sqlite3").exists()  # no database yet
    result = runner.invoke(app, ["import", str(capture)])
    out = _imported(result)
    job_id = out["preannotation_job_id"]
    assert out["samples"] == 4 and out["preannotation"] == f"job {job_id} queued"
    assert f"pre-annotation: job {job_id} queued for 4 samples" in result.output
    assert _states(data_dir) == {"unlabeled": 4}  # the job routes them
    assert _rows(data_dir, "SELECT id, kind, state FROM jobs") == [(job_id, "preannotate", "queued")]
    payload = json.loads(_rows(data_dir, "SELECT payload FROM jobs")[0][0])
    # --queue (the default): what the reviewers' queue does not take goes to the annotators
    assert payload["rest"] == "annotate" and len(payload["sample_ids"]) == 4
    assert any(p.is_file() for p in (data_dir / "broker").rglob("*"))  # handed to the workers
    # --no-queue: the samples the reviewers' queue does not take stay for round 1
    out = _imported(runner.invoke(app, ["import", str(capture), "--project", "kept", "--no-queue"]))
    payload = json.loads(_rows(data_dir, f"SELECT payload FROM jobs WHERE id = {out['preannotation_job_id']}")[0][0])
    assert payload["rest"] == "keep"


def test_without_the_detector_the_import_queues_for_annotation_and_says_why(data_dir, capture, monkeypatch, caplog):
    _detector(monkeypatch, MISSING)
    result = runner.invoke(app, ["import", str(capture)])
    out = _imported(result)
    assert f"pre-annotation off: {MISSING}; the samples go to the annotators' queue" in result.output
    assert out["preannotation"] is None and out["preannotation_job_id"] is None
    assert _states(data_dir) == {"needs_annotation": 4} and _rows(data_dir, "SELECT id FROM jobs") == []
    # Asked for by name, it is refused before anything is written.
    refused = runner.invoke(app, ["import", str(capture), "--project", "asked", "--preannotate"])
    assert refused.exit_code == 2, refused.output[-2000:]
    assert f"pre-annotation is unavailable: {MISSING}; nothing was imported" in caplog.text  # the CLI's error log
    assert _rows(data_dir, "SELECT count(*) FROM projects") == [(1,)]  # the first import only


def test_no_preannotate_imports_into_the_annotators_queue(data_dir, capture, monkeypatch):
    _detector(monkeypatch, None)
    result = runner.invoke(app, ["import", str(capture), "--no-preannotate"])
    out = _imported(result)
    assert out["preannotation"] is None and "pre-annotation" not in result.output
    assert _states(data_dir) == {"needs_annotation": 4} and _rows(data_dir, "SELECT id FROM jobs") == []


def test_no_migrate_on_an_empty_data_folder_names_the_command_to_run(data_dir, capture, monkeypatch, caplog):
    _detector(monkeypatch, None)
    data_dir.mkdir(parents=True)
    result = runner.invoke(app, ["import", str(capture), "--no-migrate"])
    assert result.exit_code == 2, result.output[-2000:]
    assert "run `handloop db upgrade` first" in caplog.text and result.exception.__class__ is SystemExit


def test_wait_follows_the_job_until_the_worker_has_routed_the_samples(data_dir, capture, monkeypatch):
    from backend.services.jobs.jobs import InMemoryJobQueue
    from backend.settings import get_settings
    from tests.support.detector_fake import FakeDetector
    from workers.tasks import preannotate
    from workers.tasks.context import build_context

    _detector(monkeypatch, None)
    monkeypatch.setattr(preannotate, "detect", FakeDetector(capture))
    ran = []

    def worker_runs_it(_seconds: float) -> bool:
        """The first wait of the follow: a worker takes the job and runs it to its end."""
        ctx = build_context(get_settings(), job_queue=InMemoryJobQueue())
        ran.append(preannotate.run_preannotation_job(ctx, ran_job_id()))
        return False

    def ran_job_id() -> int:
        return _rows(data_dir, "SELECT id FROM jobs WHERE kind = 'preannotate'")[0][0]

    monkeypatch.setattr(job_progress, "_sleep", worker_runs_it)
    result = runner.invoke(app, ["import", str(capture), "--wait"])
    out = _imported(result)
    assert len(ran) == 1 and ran[0]["fitted"] == 4
    assert "waiting for a worker" in result.output  # the follow's first read: the job still queued
    assert "pre-annotation done: 4 samples, 4 detected, 4 fitted" in result.output
    states = _states(data_dir)
    assert set(states) <= {"in_review", "needs_annotation"} and states.get("in_review", 0) >= 1, states
    assert _rows(data_dir, f"SELECT state FROM jobs WHERE id = {out['preannotation_job_id']}") == [("succeeded",)]


def test_wait_exits_1_with_the_error_of_a_failed_job(data_dir, capture, monkeypatch):
    from backend.db.session import create_engine_from_url, make_session_factory
    from backend.models.enums import JobState
    from backend.services.jobs import jobs
    from backend.settings import get_settings

    _detector(monkeypatch, None)

    def worker_fails_it(_seconds: float) -> bool:
        engine = create_engine_from_url(get_settings().resolved_database_url)
        with make_session_factory(engine).begin() as session:
            job_id = _rows(data_dir, "SELECT id FROM jobs")[0][0]
            jobs.finish(session, job_id, JobState.failed, error="the detector went missing")
        engine.dispose()
        return False

    monkeypatch.setattr(job_progress, "_sleep", worker_fails_it)
    result = runner.invoke(app, ["import", str(capture), "--wait"])
    assert result.exit_code == 1, result.output[-2000:]
    assert "pre-annotation job 1 failed: the detector went missing" in result.output
