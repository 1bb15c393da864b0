"""PostgreSQL's pool pings a connection only after it sat idle (backend.db.session): a connection in steady use
costs no extra round trip, and one that died while idle is replaced before a request sees it."""

from __future__ import annotations

import pytest
from sqlalchemy import text

from backend.db import session as db_session
from backend.db.session import create_engine_from_url

pytestmark = pytest.mark.postgres


def _count_pings(engine, monkeypatch) -> list[int]:
    pings: list[int] = []
    real = engine.dialect.do_ping
    monkeypatch.setattr(engine.dialect, "do_ping", lambda conn: pings.append(1) or real(conn))
    return pings


def test_a_connection_back_in_the_pool_a_moment_ago_is_not_pinged(pg_url, monkeypatch):
    monkeypatch.setattr(db_session, "PING_AFTER_IDLE_S", 3600.0)  # nothing counts as idle
    engine = create_engine_from_url(pg_url, pool_size=1, max_overflow=0)
    pings = _count_pings(engine, monkeypatch)
    try:
        for _ in range(3):
            with engine.connect() as conn:
                assert conn.execute(text("SELECT 1")).scalar_one() == 1
        assert pings == []
    finally:
        engine.dispose()


def test_an_idle_connection_that_died_is_replaced_before_use(pg_url, monkeypatch):
    monkeypatch.setattr(db_session, "PING_AFTER_IDLE_S", 0.0)  # every checkout counts as after idling
    engine = create_engine_from_url(pg_url, pool_size=1, max_overflow=0)
    pings = _count_pings(engine, monkeypatch)
    try:
        with engine.connect() as conn:
            first_pid = conn.execute(text("SELECT pg_backend_pid()")).scalar_one()
        admin = create_engine_from_url(pg_url, pool_size=1, max_overflow=0)
        with admin.connect() as conn:  # what a PostgreSQL restart does to the pooled connection
            conn.execute(text("SELECT pg_terminate_backend(:pid)"), {"pid": first_pid})
        admin.dispose()
        with engine.connect() as conn:
            assert conn.execute(text("SELECT pg_backend_pid()")).scalar_one() != first_pid
        assert len(pings) >= 1
    finally:
        engine.dispose()
