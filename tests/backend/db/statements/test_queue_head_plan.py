"""PostgreSQL reads a queue's head from an index in the queue's order: the annotate queue from ix_samples_queue, even
with statistics from when every sample was in the queue (a project's start), so a lease does not walk past the
samples already done (backend/db/statements/lease_statement.py: free_pick); the review queue from
ix_samples_review_queue, so a lease does not sort every sample in review (migration 0009)."""

from __future__ import annotations

import json
from datetime import timedelta

import pytest
from sqlalchemy import create_engine, update
from sqlalchemy.dialects import postgresql

from backend.db.base import utcnow
from backend.db.session import make_session_factory
from backend.db.statements.lease_statement import acquire_statement
from backend.models.capture import Sample
from backend.models.enums import LeaseKind, Role, SampleState
from backend.models.users import User
from backend.services.captures.seed import seed_samples
from backend.services.leases import queues

pytestmark = pytest.mark.postgres

DONE = 2000


def _plan_nodes(node: dict) -> list[dict]:
    return [node, *(n for child in node.get("Plans", ()) for n in _plan_nodes(child))]


def _explain_lease(engine, kind: LeaseKind, user_id: int) -> list[dict]:
    """The plan nodes of the one-statement lease, run (and rolled back) as psycopg's prepared statement runs."""
    statement = acquire_statement(kind).compile(dialect=postgresql.psycopg.dialect())
    now = utcnow()
    params = statement.construct_params({"user_id": user_id, "now": now, "expires": now + timedelta(minutes=5),
                                         "token": "t" * 16})
    params = {k: json.dumps(v) if isinstance(v, dict) else v for k, v in params.items()}  # the JSON audit data
    with engine.connect() as conn:
        conn.exec_driver_sql("SET plan_cache_mode = force_generic_plan")
        plan = conn.exec_driver_sql("EXPLAIN (ANALYZE, FORMAT JSON) " + str(statement), params).scalar()
        conn.rollback()
    return _plan_nodes((plan if isinstance(plan, list) else json.loads(plan))[0]["Plan"])


def test_the_review_lease_reads_the_most_confident_first_from_the_review_index(pg_url) -> None:
    engine = create_engine(pg_url)
    try:
        with make_session_factory(engine).begin() as session:
            ids = sorted(seed_samples(session, frames=2500, cameras=1))
            user_id = session.query(User.id).filter(User.role == Role.reviewer).limit(1).scalar()
        with engine.begin() as conn:  # in review with confidences, some without one (fitted from annotations)
            conn.exec_driver_sql("UPDATE samples SET state = 'in_review', confidence = "
                                 "CASE WHEN mod(id, 7) = 0 THEN NULL ELSE mod(id * 7919, 1000) / 1000.0 END")
            best = conn.exec_driver_sql("SELECT id FROM samples ORDER BY confidence DESC NULLS LAST, id "
                                        "LIMIT 1").scalar()
        with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
            conn.exec_driver_sql("ANALYZE samples")
        nodes = _explain_lease(engine, LeaseKind.review, user_id)
        scans = [n for n in nodes if n.get("Relation Name") == "samples" and "Index Name" in n]
        assert any(n["Index Name"] == "ix_samples_review_queue" and n["Actual Rows"] == 1 for n in scans), scans
        assert not [n for n in nodes if n["Node Type"] == "Sort" and n.get("Actual Rows", 0) > 1]  # no queue sorted
        with make_session_factory(engine).begin() as session:  # and the lease is the queue's head
            reviewer = session.get(User, user_id)
            assert queues.acquire(session, reviewer, LeaseKind.review, 60).sample_id == best
        assert best in ids
    finally:
        engine.dispose()


def test_the_lease_reads_the_queue_head_past_done_samples_from_the_queue_index(pg_url) -> None:
    engine = create_engine(pg_url)
    try:
        with make_session_factory(engine).begin() as session:
            ids = sorted(seed_samples(session, frames=DONE + 500, cameras=1))
            user_id = session.query(User.id).filter(User.role == Role.annotator).limit(1).scalar()
        with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
            conn.exec_driver_sql("ANALYZE samples")  # every sample in the queue, as at a project's start
        with engine.begin() as conn:  # the first frames done since; the statistics not renewed
            conn.execute(update(Sample).where(Sample.id.in_(ids[:DONE])).values(state=SampleState.accepted))
        nodes = _explain_lease(engine, LeaseKind.annotate, user_id)
        taken = [n for n in nodes if n.get("CTE Name") == "free" and n.get("Node Type") == "CTE Scan"]
        assert taken and taken[0]["Actual Rows"] == 1  # a sample was leased
        scans = [n for n in nodes if n.get("Relation Name") == "samples" and "Index Name" in n]
        assert any(n["Index Name"] == "ix_samples_queue" and n["Actual Rows"] == 1 for n in scans), scans
        assert sum(n.get("Rows Removed by Filter", 0) for n in nodes) < 50  # the done samples were not read
    finally:
        engine.dispose()
