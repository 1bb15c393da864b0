"""A progress write locks the parent job's row (round, heartbeat or pre-annotation parent) before any of its
own jobs' rows: the order every other writer keeps (round_progress.lock, rounds.cancel). The other order could
deadlock on PostgreSQL with a cancel holding the round and waiting for a child."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sqlalchemy import event
from sqlalchemy.engine import Engine

from backend.models.enums import JobKind, JobState
from backend.models.jobs import Job
from backend.services.jobs import jobs
from tests.support.annotator_world import annotator_world
from tests.support.live_stack import tiny_capture
from workers.tasks.progress import ProgressReporter


@pytest.fixture
def world(tmp_path, capture_cache):
    with annotator_world(tmp_path / "data", tiny_capture(capture_cache, frames=1)) as world:
        yield world


def _running_jobs(ctx, queue) -> tuple[int, int]:
    with ctx.session_factory.begin() as session:
        parent = jobs.create(session, queue, JobKind.round, enqueue=False)
        child = jobs.create(session, queue, JobKind.fit, enqueue=False)
        parent.state = child.state = JobState.running
        session.flush()
        return parent.id, child.id


def _job_ids_in_order(statements: list[tuple[str, object]]) -> Iterator[int]:
    """The job ids that statements on the jobs table name, in execution order."""
    for sql, params in statements:
        if "jobs" not in sql.split("WHERE")[0] or "WHERE" not in sql:
            continue
        values = params.values() if isinstance(params, dict) else params if isinstance(params, (tuple, list)) else ()
        yield from (v for v in values if isinstance(v, int))


@pytest.mark.parametrize("role", ["heartbeat_of", "round_of", "parent"])
def test_a_progress_write_locks_the_parent_before_its_own_jobs(world, role):
    _, _, queue, ctx = world
    parent_id, child_id = _running_jobs(ctx, queue)
    kwargs = {"parent": (parent_id, 0.0, 0.5)} if role == "parent" else {role: parent_id}
    reporter = ProgressReporter(ctx, [child_id], **kwargs)
    statements: list[tuple[str, object]] = []

    def record(conn, cursor, statement, parameters, context, executemany):
        statements.append((statement, parameters))

    event.listen(Engine, "before_cursor_execute", record)
    try:
        reporter(0.25, "fitting", force=True)
    finally:
        event.remove(Engine, "before_cursor_execute", record)
    named = [i for i in _job_ids_in_order(statements) if i in (parent_id, child_id)]
    assert named and named[0] == parent_id, (role, named, [s for s, _ in statements])
    with ctx.session_factory() as session:  # and the write itself still happened
        assert session.get(Job, child_id).progress == pytest.approx(0.25)
