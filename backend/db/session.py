"""Engines and sessions for SQLite (embedded mode) and PostgreSQL (scale-out)."""

from __future__ import annotations

import time
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.exc import DisconnectionError
from sqlalchemy.orm import Session, sessionmaker


def create_engine_from_url(url: str, *, pool_size: int = 10, max_overflow: int = 20, echo: bool = False) -> Engine:
    """An engine configured for its backend.

    SQLite: every transaction starts with BEGIN IMMEDIATE, so a transaction holds the single writer lock
    from its first statement; a lease taken by select-then-update cannot race another writer. WAL mode
    lets readers of other connections proceed meanwhile. Connections of `read_only_engine(engine)` begin
    deferred instead (plain BEGIN): they read a snapshot without taking the writer lock.
    """
    if url.startswith("sqlite"):
        engine = create_engine(url, echo=echo, connect_args={"check_same_thread": False, "timeout": 30})

        @event.listens_for(engine, "connect")
        def _sqlite_connect(dbapi_connection: Any, _record: Any) -> None:
            dbapi_connection.isolation_level = None  # we issue BEGIN ourselves
            cursor = dbapi_connection.cursor()
            if ":memory:" not in url:
                cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.execute("PRAGMA busy_timeout=30000")
            cursor.close()

        @event.listens_for(engine, "begin")
        def _sqlite_begin(connection: Any) -> None:
            read_only = connection.get_execution_options().get(READ_ONLY_OPTION, False)
            connection.exec_driver_sql("BEGIN" if read_only else "BEGIN IMMEDIATE")

        return engine
    engine = create_engine(url, echo=echo, pool_size=pool_size, max_overflow=max_overflow)
    _ping_idle_connections(engine)
    return engine


# A pooled PostgreSQL connection idle longer than this is pinged before use (PostgreSQL restarted, a proxy
# or firewall dropped it). Pinging every checkout (pool_pre_ping) was a round trip per request; a connection
# in steady use is not pinged, and if it died anyway the request fails once and SQLAlchemy, seeing the
# disconnect, replaces every connection of the pool.
PING_AFTER_IDLE_S = 1.0


def _ping_idle_connections(engine: Engine) -> None:
    @event.listens_for(engine, "connect")
    def _fresh(_dbapi_connection: Any, record: Any) -> None:
        record.info["checked_in_s"] = time.monotonic()

    @event.listens_for(engine, "checkin")
    def _checked_in(_dbapi_connection: Any, record: Any) -> None:
        record.info["checked_in_s"] = time.monotonic()

    @event.listens_for(engine, "checkout")
    def _checkout(dbapi_connection: Any, record: Any, _proxy: Any) -> None:
        if time.monotonic() - record.info.get("checked_in_s", 0.0) < PING_AFTER_IDLE_S:
            return
        try:
            engine.dialect.do_ping(dbapi_connection)
        except Exception as exc:  # the pool discards this connection and checks out another
            raise DisconnectionError(f"pooled connection is gone: {exc}") from exc


READ_ONLY_OPTION = "handloop_read_only"


def read_only_engine(engine: Engine) -> Engine:
    """The same engine and pool for transactions that only read (GET requests). On SQLite they begin deferred,
    so serving images, statistics or progress never waits for (or blocks) the single writer; a write in such a
    transaction would have to upgrade its lock and may fail as 'database busy'. PostgreSQL: unchanged."""
    return engine.execution_options(**{READ_ONLY_OPTION: True})


def make_session_factory(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(bind=engine, expire_on_commit=False, autoflush=False)
