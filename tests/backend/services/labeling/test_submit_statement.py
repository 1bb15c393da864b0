"""A submission as one statement (backend.db.statements.submit_statement.SUBMIT_ALONE, the route's path on PostgreSQL):
what it writes, that a failed check writes nothing and the checked path names the error, idempotent retries
and a client id taken meanwhile; on both databases (SQLite takes the checked path: same results)."""

from __future__ import annotations

import json
import threading
import uuid
from datetime import timedelta

import pytest
from sqlalchemy import event, text
from sqlalchemy.dialects import postgresql
from sqlalchemy.orm import Session

from backend.db.base import utcnow
from backend.db.statements.submit_statement import SUBMIT, SUBMIT_ALONE
from backend.models.drafts import Draft
from backend.models.enums import LeaseKind, Role
from backend.models.users import User
from backend.schemas.tasks import SubmissionCreate
from backend.services.accounts.users import create_user
from backend.services.captures.seed import seed_samples
from backend.services.captures.storage import LocalDiskStorage
from backend.services.errors import (
    ConflictError,
    InvalidInputError,
    LeaseExpiredError,
    NotFoundError,
    PermissionDeniedError,
    ServiceUnavailableError,
)
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.services.labeling import submissions
from backend.services.leases import queues
from backend.services.transactions import run_after_commit
from tests.support.concurrency import all_at_once

TABLES = ("submissions", "clicks", "jobs", "audit_events", "drafts")
N_THREADS = 8


@pytest.mark.parametrize("statement", [SUBMIT, SUBMIT_ALONE], ids=["after-lock", "alone"])
def test_the_submit_statements_fit_psycopgs_query_cache(statement):
    """Beyond 4096 bytes psycopg parses the text again on every execution (see test_lease_statement_size)."""
    compiled = str(statement.compile(dialect=postgresql.psycopg.dialect()))
    assert "INSERT INTO clicks" in compiled and len(compiled.encode()) < 4096, len(compiled.encode())


@pytest.fixture
def world(db_url, engine_factory, tmp_path):
    return _world(db_url, engine_factory, tmp_path)


def _world(url, engine_factory, tmp_path) -> dict:
    """Two samples of two 96x96 views; annotators `a` (holding a lease on the first, with a draft of it) and
    `b`."""
    factory = engine_factory(url)
    with factory() as s, s.begin():
        sids = seed_samples(s, frames=2, cameras=2)
        a = create_user(s, "a@x.org", "password-123", Role.annotator).id
        b = create_user(s, "b@x.org", "password-123", Role.annotator).id
    with factory() as s, s.begin():
        lease = queues.acquire(s, s.get(User, a), LeaseKind.annotate, 60)
        assert lease is not None and lease.sample_id == sids[0]
        s.add(Draft(sample_id=sids[0], kind=LeaseKind.annotate.value, user_id=a, lease_token=lease.token, revision=1,
                    payload={}, size_bytes=2))
        views = list(s.execute(text("SELECT id FROM views WHERE sample_id = :s ORDER BY id"),
                               {"s": sids[0]}).scalars())
        other_view = s.execute(text("SELECT min(id) FROM views WHERE sample_id = :s"), {"s": sids[1]}).scalar_one()
    return {"factory": factory, "sids": sids, "a": a, "b": b, "token": lease.token, "views": views,
            "other_view": other_view, "queue": InMemoryJobQueue(), "storage": LocalDiskStorage(tmp_path)}


def _body(w, client_id: str | None = None, **overrides) -> SubmissionCreate:
    clicks = [{"view_id": v, "keypoint": k, "x": 5.0 + k, "y": 95.5} for v in w["views"] for k in (0, 4, 8)]
    data = {"submission_id": client_id or uuid.uuid4().hex, "lease_token": w["token"], "time_spent_s": 3.5,
            "clicks": clicks, **overrides}
    return SubmissionCreate.model_validate(data)


def _submit(w, body: SubmissionCreate, user: str = "a", sample: int = 0) -> submissions.SubmitResult:
    """As the route does: a fresh session, the sole-statement path, commit (then the after-commit hand-off)."""
    factory = w["factory"]
    with factory() as s:
        actor = s.get(User, w[user])
        s.commit()
        result = submissions.submit(s, w["queue"], w["storage"], actor, w["sids"][sample], body, 100,
                                    sole_statement=True)
        s.commit()
        run_after_commit(s)
    return result


def _counts(w) -> dict[str, int]:
    with w["factory"]() as s:
        return {t: s.execute(text(f"SELECT count(*) FROM {t}")).scalar_one() for t in TABLES}


def _sample(w, index: int = 0):
    with w["factory"]() as s:
        return s.execute(text("SELECT state, leased_by_id, lease_token FROM samples WHERE id = :s"),
                         {"s": w["sids"][index]}).one()


def test_a_submission_writes_everything_and_is_one_statement_on_postgresql(world):
    w = world
    executed: list[str] = []
    engine = w["factory"].kw["bind"]
    listen = lambda conn, cursor, statement, *args: executed.append(statement)  # noqa: E731
    before = _counts(w)
    event.listen(engine, "before_cursor_execute", listen)
    try:
        result = _submit(w, _body(w, "one-statement-1"))
    finally:
        event.remove(engine, "before_cursor_execute", listen)
    if engine.dialect.name == "postgresql":  # no lock statement, no BEGIN/COMMIT round trips around it
        assert [s.lstrip()[:18] for s in executed if "samples" in s] == ["WITH smp AS (\n  UP"], executed
        assert len([s for s in executed if "users" not in s]) == 1, executed
    info = result.submission
    assert not result.duplicate and info.n_clicks == 6 and info.n_masks == 0 and info.fit_job_id is not None
    after = _counts(w)
    assert {t: after[t] - before[t] for t in TABLES} == {"submissions": 1, "clicks": 6, "jobs": 1,
                                                         "audit_events": 4, "drafts": -1}
    assert tuple(_sample(w)) == ("fitting", None, None)
    assert w["queue"].enqueued == [(info.fit_job_id, "fit")]
    with w["factory"]() as s:
        clicks = s.execute(text("SELECT view_id, keypoint, x_px, y_px, visibility, from_proposal, user_id "
                                "FROM clicks WHERE submission_id = :i ORDER BY view_id, keypoint"),
                           {"i": info.id}).all()
        job = s.execute(text("SELECT kind, state, sample_id, payload, dispatched_at IS NOT NULL FROM jobs")).one()
        actions = s.execute(text("SELECT action, data FROM audit_events WHERE entity_id IN (:s, :j) "
                                 "AND action <> 'lease.acquire' ORDER BY id"),
                            {"s": str(w["sids"][0]), "j": str(info.fit_job_id)}).all()
    assert [tuple(c) for c in clicks] == [(v, k, 5.0 + k, 95.5, "visible", False, w["a"])
                                         for v in w["views"] for k in (0, 4, 8)]
    payload = job[3] if isinstance(job[3], dict) else json.loads(job[3])
    assert tuple(job[:3]) == ("fit", "queued", w["sids"][0]) and job[4]
    assert payload == {"client_submission_id": "one-statement-1", "source": "annotation"}
    assert [a for a, _ in actions] == ["job.create", "sample.state", "sample.state", "submission.create"]


def _expire(w) -> None:
    with w["factory"]() as s, s.begin():
        s.execute(text("UPDATE samples SET lease_expires_at = :t WHERE id = :s"),
                  {"t": utcnow() - timedelta(seconds=1), "s": w["sids"][0]})


def _cases():
    return [
        ("wrong lease token", lambda w: _body(w, lease_token="not-the-token"), "a", 0, PermissionDeniedError,
         "token does not match"),
        ("another annotator", lambda w: _body(w), "b", 0, PermissionDeniedError, "you hold no annotate lease"),
        ("a sample not leased", lambda w: _body(w), "a", 1, PermissionDeniedError, "you hold no annotate lease"),
        ("click outside the image", lambda w: _body(w, clicks=[
            {"view_id": w["views"][0], "keypoint": 0, "x": 95.6, "y": 1.0}]), "a", 0, InvalidInputError,
         "outside view"),
        ("click left of the image", lambda w: _body(w, clicks=[
            {"view_id": w["views"][1], "keypoint": 0, "x": -0.51, "y": 1.0}]), "a", 0, InvalidInputError,
         "outside view"),
        ("view of another sample", lambda w: _body(w, clicks=[
            {"view_id": w["other_view"], "keypoint": 0, "x": 1.0, "y": 1.0}]), "a", 0, InvalidInputError,
         "is not a view of sample"),
        ("keypoint given twice", lambda w: _body(w, clicks=[
            {"view_id": w["views"][0], "keypoint": 3, "x": 1.0, "y": 1.0},
            {"view_id": w["views"][0], "keypoint": 3, "x": 2.0, "y": 1.0}]), "a", 0, InvalidInputError, "twice"),
        ("unknown sample", lambda w: _body(w), "a", None, NotFoundError, "not found"),
        ("expired lease", lambda w: (_expire(w), _body(w))[1], "a", 0, LeaseExpiredError, "expired"),
    ]


@pytest.mark.parametrize(("case", "make", "user", "sample", "error", "message"), _cases(),
                         ids=[c[0] for c in _cases()])
def test_a_failed_check_writes_nothing_and_names_the_error(world, case, make, user, sample, error, message):
    w = world
    body = make(w)
    before, held = _counts(w), tuple(_sample(w))
    if sample is None:
        w["sids"] = [*w["sids"], 2**31 - 1]
        sample = 2
    with pytest.raises(error, match=message):
        _submit(w, body, user, sample)
    assert _counts(w) == before and tuple(_sample(w)) == held and w["queue"].enqueued == []


def test_a_broker_outage_is_a_503_that_writes_nothing(world):
    w = world
    w["queue"].available = False
    before = _counts(w)
    with pytest.raises(ServiceUnavailableError):
        _submit(w, _body(w))
    assert _counts(w) == before and _sample(w)[0] == "needs_annotation"


def test_a_retry_returns_the_first_submission(world):
    w = world
    first = _submit(w, _body(w, "retry-client-1"))
    before = _counts(w)
    again = _submit(w, _body(w, "retry-client-1"))
    assert again.duplicate and again.submission.id == first.submission.id
    assert _counts(w) == before


def test_a_client_id_used_for_another_sample_is_refused(world):
    w = world
    _submit(w, _body(w, "used-elsewhere-1"))
    with w["factory"]() as s, s.begin():  # `a` takes the next sample
        lease = queues.acquire(s, s.get(User, w["a"]), LeaseKind.annotate, 60)
        assert lease is not None and lease.sample_id == w["sids"][1]
        views = list(s.execute(text("SELECT id FROM views WHERE sample_id = :s"), {"s": w["sids"][1]}).scalars())
    before = _counts(w)
    body = SubmissionCreate.model_validate({"submission_id": "used-elsewhere-1", "lease_token": lease.token,
                                            "time_spent_s": 1.0,
                                            "clicks": [{"view_id": views[0], "keypoint": 0, "x": 1.0, "y": 1.0}]})
    with pytest.raises(ConflictError, match="already used"):
        _submit(w, body, "a", 1)
    assert _counts(w) == before and _sample(w, 1)[0] == "needs_annotation"


def test_concurrent_retries_write_once(world):
    w = world
    body = _body(w, "twin-" + uuid.uuid4().hex[:12])
    def submit(release) -> submissions.SubmitResult:
        release()
        return _submit(w, body)

    results = all_at_once(N_THREADS, submit)
    assert sorted(r.duplicate for r in results) == [False] + [True] * (N_THREADS - 1)
    assert len({r.submission.id for r in results}) == 1
    counts = _counts(w)
    assert (counts["submissions"], counts["clicks"], counts["jobs"]) == (1, 6, 1)
    assert _sample(w)[0] == "fitting" and len(w["queue"].enqueued) == 1


@pytest.mark.postgres
def test_a_client_id_taken_while_the_statement_waits_writes_nothing(pg_url, engine_factory, tmp_path):
    """The gate's NOT EXISTS cannot see an uncommitted twin; the submission INSERT then waits on the unique
    index and fails when the twin commits: the whole statement is undone (in autocommit nothing may stay
    half-written), and the checked path answers 409."""
    w = _world(pg_url, engine_factory, tmp_path)
    factory = w["factory"]
    body = _body(w, "taken-meanwhile-1")
    holder: Session = factory()
    holder.execute(text("INSERT INTO submissions (client_id, sample_id, user_id, time_spent_s, n_clicks, n_masks, "
                        "created_at) VALUES ('taken-meanwhile-1', :s, :u, 1.0, 0, 0, :t)"),
                   {"s": w["sids"][1], "u": w["b"], "t": utcnow()})
    before = _counts(w)
    outcome: list[BaseException | submissions.SubmitResult] = []

    def submitter() -> None:
        try:
            outcome.append(_submit(w, body))
        except BaseException as exc:
            outcome.append(exc)

    thread = threading.Thread(target=submitter)
    thread.start()
    with factory() as watch:  # until the statement waits on the holder's uncommitted row (or has finished)
        for _ in range(600):
            if not thread.is_alive() or watch.execute(text(
                    "SELECT count(*) FROM pg_stat_activity WHERE wait_event_type = 'Lock' "
                    "AND query LIKE 'WITH smp AS%'")).scalar_one():
                break
            thread.join(0.05)
    waited = thread.is_alive()
    holder.commit()
    holder.close()
    thread.join(60)
    assert waited, "the statement did not wait on the unique index"
    assert len(outcome) == 1 and isinstance(outcome[0], ConflictError), outcome
    after = _counts(w)
    assert after == {**before, "submissions": before["submissions"] + 1}  # only the holder's row
    assert _sample(w)[0] == "needs_annotation" and w["queue"].enqueued == []
