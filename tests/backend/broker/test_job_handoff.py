"""The job hand-off: claims that make redelivery harmless, the broker check that refuses writes (503), and
the outbox that re-sends jobs whose hand-off failed after their commit."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import threading
from datetime import timedelta

import pytest
from sqlalchemy import text

from backend.broker import outbox as dispatch
from backend.broker import worker_processes
from backend.broker.celery_queue import BatchingSender, CeleryJobQueue, task_for_job
from backend.db.base import utcnow
from backend.models.enums import JobKind, JobState, Role
from backend.models.jobs import Job
from backend.services.errors import ServiceUnavailableError
from backend.services.jobs import jobs
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.settings import Settings


def _new_job(env, **values) -> int:
    with env.session() as session, session.begin():
        job = jobs.create(session, InMemoryJobQueue(), JobKind.fit, payload={"source": "annotation"})
        for key, value in values.items():
            setattr(job, key, value)
        session.flush()
        return job.id


def test_claim_starts_skips_duplicates_and_takes_over_dead_jobs(env):
    job_id = _new_job(env)
    started = utcnow()  # the claims are told the time: no window around the clock
    with env.session() as session, session.begin():
        job = jobs.claim(session, job_id, "w1:1", stale_after_s=60, now=started)
        assert job.state == JobState.running and job.attempts == 1 and job.worker == "w1:1"
    with env.session() as session, session.begin():  # may be alive: the delivery must come back, not be dropped
        with pytest.raises(jobs.JobStillRunningError) as busy:
            jobs.claim(session, job_id, "w2:2", stale_after_s=60, now=started + timedelta(seconds=10))
        assert busy.value.job_ids == [job_id] and busy.value.workers == ["w1:1"]
        # when the heartbeat will be stale (60 - 10 s), and a second more
        assert busy.value.retry_after_s == pytest.approx(51.0, abs=1e-3)
    with env.session() as session, session.begin():
        session.execute(text("UPDATE jobs SET updated_at = :t WHERE id = :i"),
                        {"t": utcnow() - timedelta(seconds=120), "i": job_id})
    with env.session() as session, session.begin():
        job = jobs.claim(session, job_id, "w2:2", stale_after_s=60)  # its worker died: taken over
        assert job.attempts == 2 and job.worker == "w2:2" and "taken over" in job.message
        jobs.finish(session, job_id, JobState.succeeded)
    with env.session() as session, session.begin():
        assert jobs.claim(session, job_id, "w3:3", stale_after_s=0) is None  # final: nothing to do


def test_an_attempt_records_its_start_and_a_finished_job_keeps_no_progress_message(env):
    job_id = _new_job(env)
    with env.session() as session, session.begin():
        assert jobs.get(session, job_id).started_at is None  # queued: no worker has started it
        session.execute(text("UPDATE jobs SET created_at = :t WHERE id = :i"),
                        {"t": utcnow() - timedelta(seconds=300), "i": job_id})  # it waited 5 minutes
    before = utcnow()
    with env.session() as session, session.begin():
        jobs.claim(session, job_id, "w1:1", stale_after_s=60)
        jobs.update_progress(session, job_id, 0.0, "predicting 0/16")
    with env.session() as session, session.begin():
        jobs.finish(session, job_id, JobState.succeeded)
    with env.session() as session:
        job = jobs.get(session, job_id)
        assert job.started_at >= before and job.finished_at >= job.started_at
        assert (job.started_at - job.created_at).total_seconds() >= 300  # the wait is not in the duration
        assert job.message == "" and job.progress == 1.0


@pytest.fixture
def dead_process() -> str:
    """The identity of a process of this machine that has exited (backend.broker.worker_processes)."""
    child = subprocess.Popen([sys.executable, "-c", "import os, sys; "
                              "from backend.broker import worker_processes; print(worker_processes.current())"],
                             stdout=subprocess.PIPE, text=True)
    identity = child.communicate(timeout=60)[0].strip()
    assert identity != "None", "no process identity on this machine (no /proc)"
    return identity


def test_a_job_whose_process_is_gone_is_taken_over_at_once_after_a_fresh_heartbeat(env, dead_process):
    # The race of issue 13: a worker killed right after a heartbeat, its task delivered again at once. The
    # claimant sees the attempt's process gone and takes the job over instead of dropping the delivery.
    job_id = _new_job(env)
    with env.session() as session, session.begin():
        jobs.claim(session, job_id, "w1:1", stale_after_s=600, process=dead_process)
    with env.session() as session, session.begin():
        job = jobs.claim(session, job_id, "w2:2", stale_after_s=600, process=worker_processes.current())
        assert job is not None and job.attempts == 2 and "taken over" in job.message
        assert job.worker_process == worker_processes.current()


def test_a_live_process_or_one_on_another_machine_keeps_its_job_until_its_heartbeat_is_stale(env):
    job_id = _new_job(env)
    here = worker_processes.current()
    elsewhere = "00000000-0000-0000-0000-000000000000/4026531836/12345/678"
    for process in (here, elsewhere, None):
        beat = utcnow()  # the claims are told the time: no window around the clock
        with env.session() as session, session.begin():
            session.execute(text("UPDATE jobs SET state = 'running', updated_at = :t, worker_process = :p "
                                 "WHERE id = :i"), {"t": beat, "p": process, "i": job_id})
        with env.session() as session, session.begin():  # its heartbeat 5 s old
            with pytest.raises(jobs.JobStillRunningError) as busy:
                jobs.claim(session, job_id, "w2:2", stale_after_s=60, process=here, now=beat + timedelta(seconds=5))
            assert busy.value.retry_after_s == pytest.approx(56.0, abs=1e-3), process
        with env.session() as session, session.begin():  # the retry, once the heartbeat is stale: taken over
            assert jobs.claim(session, job_id, "w2:2", stale_after_s=60, process=here,
                              now=beat + timedelta(seconds=5 + 56)) is not None, process
    assert not worker_processes.is_gone(here) and not worker_processes.is_gone(elsewhere)
    assert not worker_processes.is_gone(None) and not worker_processes.is_gone("garbage")


def test_a_job_that_keeps_dying_fails_after_max_attempts_and_releases_its_sample(env, h):
    sample_id = h.seed(env, frames=1, state="fitting")[0]
    with env.session() as session, session.begin():
        job_id = jobs.create(session, InMemoryJobQueue(), JobKind.fit, sample_id=sample_id).id
    for attempt in (1, 2):
        with env.session() as session, session.begin():
            assert jobs.claim(session, job_id, f"w{attempt}", stale_after_s=0, max_attempts=2).attempts == attempt
    with env.session() as session, session.begin():
        assert jobs.claim(session, job_id, "w3", stale_after_s=0, max_attempts=2) is None
    with env.session() as session:
        job = session.get(Job, job_id)
        assert job.state == JobState.failed and "gave up after 2 attempts" in job.error
        assert session.execute(text("SELECT state FROM samples WHERE id = :i"), {"i": sample_id}).scalar_one() \
            == "needs_annotation"


def test_unavailable_queue_refuses_a_submission_with_503_and_writes_nothing(env, h):
    h.seed(env, frames=2)
    task = h.next_task(env)
    before = {t: h.count(env, t) for t in ("jobs", "submissions", "clicks", "audit_events")}
    env.queue.available = False
    response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=h.body(task),
                               headers=env.headers(Role.annotator))
    assert response.status_code == 503, response.text
    assert "nothing was written" in response.json()["detail"] and response.headers["retry-after"]
    assert {t: h.count(env, t) for t in before} == before
    env.queue.available = True
    response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=h.body(task),
                               headers=env.headers(Role.annotator))
    assert response.status_code == 201, response.text


def test_unavailable_queue_refuses_a_round_launch(env):
    env.queue.available = False
    response = env.client.post("/api/admin/rounds", json={"note": "x"}, headers=env.headers(Role.admin))
    assert response.status_code == 503, response.text
    assert env.client.get("/api/admin/rounds", headers=env.headers(Role.admin)).json() == []


def test_outbox_resends_undispatched_stale_and_dead_jobs_only(env):
    settings = env.settings.model_copy(update={"job_redispatch_after_s": 600, "job_heartbeat_timeout_s": 60})
    now = utcnow()
    fresh = _new_job(env)  # just handed over: left alone
    failed_handoff = _new_job(env, dispatched_at=None)
    lost = _new_job(env, dispatched_at=now - timedelta(seconds=700))
    dead = _new_job(env, state=JobState.running)
    alive = _new_job(env, state=JobState.running)
    done = _new_job(env, dispatched_at=None, state=JobState.succeeded)
    old = now - timedelta(seconds=200)
    with env.session() as session, session.begin():
        session.execute(text("UPDATE jobs SET updated_at = :t, dispatched_at = :t WHERE id = :i"),
                        {"t": old, "i": dead})
    sent: list[int] = []
    assert dispatch.redispatch(env.session_factory, lambda i, k, p: sent.append(i) or True, settings) == 3
    assert sorted(sent) == sorted([failed_handoff, lost, dead])
    assert fresh not in sent and alive not in sent and done not in sent
    with env.session() as session:
        dead_row = session.get(Job, dead)
        assert abs((dead_row.updated_at - old).total_seconds()) < 1e-3  # the heartbeat is not faked
        assert session.get(Job, failed_handoff).dispatched_at is not None
    sent.clear()
    assert dispatch.redispatch(env.session_factory, lambda i, k, p: sent.append(i) or True, settings) == 0
    # A failing send stops the pass and leaves the job due.
    again = _new_job(env, dispatched_at=None)
    assert dispatch.redispatch(env.session_factory, lambda i, k, p: False, settings) == 0
    with env.session() as session:
        assert session.get(Job, again).dispatched_at is None


def test_celery_queue_reports_an_unreachable_broker_and_marks_failed_handoffs(env, tmp_path):
    settings = Settings(data_dir=tmp_path, broker_url="redis://127.0.0.1:1/0", environment="test",
                        secret_key="x" * 20, database_url=env.settings.database_url)
    queue = CeleryJobQueue(settings)
    with pytest.raises(ServiceUnavailableError, match="unreachable"):
        queue.ensure_available()
    queue._session_factory = env.session_factory
    job_id = _new_job(env)
    queue.enqueue(job_id, "fit")  # must not raise
    with env.session() as session:
        assert session.get(Job, job_id).dispatched_at is None
    embedded = CeleryJobQueue(Settings(data_dir=tmp_path / "e", environment="test", secret_key="x" * 20))
    embedded.ensure_available()
    assert embedded.send(job_id, "fit") is True
    assert list((tmp_path / "e" / "broker" / "messages").iterdir())  # the message is a file


def test_each_job_kind_maps_to_its_task():
    assert task_for_job("fit") == "handloop.fit" and task_for_job("round") == "handloop.round"
    assert task_for_job("train", {"net": "mvnet"}) == "handloop.train_mvnet"
    assert task_for_job("train", {"net": "handsegnet"}) == "handloop.train_handsegnet"
    assert task_for_job("predict") == "handloop.predict_batch"
    assert task_for_job("export") == "handloop.export_freihand"  # the admin page's FreiHAND export (issue 38)
    assert task_for_job("import_capture") is None  # imports run in the request


def test_visibility_timeout_must_exceed_the_longest_task(tmp_path):
    with pytest.raises(ValueError, match="visibility"):
        Settings(data_dir=tmp_path, broker_visibility_timeout_s=100, task_time_limit_s=200)


def test_fit_jobs_are_sent_several_per_message():
    sent: list[list[int]] = []
    failed: list[list[int]] = []
    release = threading.Event()

    def send(ids: list[int]) -> bool:
        release.wait(5)  # the first send is slow: what arrives meanwhile goes into the next message
        sent.append(list(ids))
        return ids[0] != 100

    sender = BatchingSender(send, failed.append, max_batch=3, linger_s=0.05)
    for job_id in range(1, 6):
        sender.put(job_id)
    release.set()
    sender.put(100)
    sender.close()
    assert sorted(i for batch in sent for i in batch) == [1, 2, 3, 4, 5, 100]  # every job once
    assert all(1 <= len(batch) <= 3 for batch in sent) and len(sent) < 6
    assert failed == [batch for batch in sent if batch[0] == 100]  # a refused send goes back to the outbox


def test_celery_queue_sends_buffered_fits_as_one_message(env, tmp_path):
    settings = Settings(data_dir=tmp_path, environment="test", secret_key="x" * 20, fit_dispatch_linger_s=0.5)
    queue = CeleryJobQueue(settings)
    queue.start(env.session_factory)
    try:
        for job_id in (11, 12, 13):
            queue.enqueue(job_id, "fit")
    finally:
        queue.stop()  # sends what is buffered
    messages = list((tmp_path / "broker" / "messages").iterdir())
    assert len(messages) == 1
    body = json.loads(base64.b64decode(json.loads(messages[0].read_text())["body"]))
    assert body[0] == [[11, 12, 13]]  # the task's args: one list of job ids
