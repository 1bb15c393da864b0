"""GET requests read without SQLite's writer lock: images and progress are served while a writer holds it."""

from __future__ import annotations

import sqlite3
import threading

from sqlalchemy import text

from backend.models.enums import Role


def _hold_writer_lock(path: str) -> sqlite3.Connection:
    conn = sqlite3.connect(path, isolation_level=None, timeout=0)
    conn.execute("BEGIN IMMEDIATE")  # what every writing transaction of the app takes first
    return conn


def test_get_requests_are_served_while_a_writer_holds_the_lock(sqlite_env, h):
    env = sqlite_env
    h.seed(env, frames=1, cameras=1)
    with env.session() as s:
        view_id, key = s.execute(text("SELECT id, image_key FROM views")).one()
    env.client.app.state.storage.put_bytes(key, b"\x89PNG fake")
    headers = env.headers(Role.admin)
    env.client.get("/api/auth/me", headers=headers)  # warm the token cache outside the lock

    holder = _hold_writer_lock(env.settings.resolved_database_url.removeprefix("sqlite:///"))
    try:
        answers: dict[str, int] = {}

        def get_all() -> None:
            answers["image"] = env.client.get(f"/api/files/views/{view_id}/image", headers=headers).status_code
            answers["statistics"] = env.client.get("/api/admin/rounds/statistics", headers=headers).status_code

        reader = threading.Thread(target=get_all, daemon=True)
        reader.start()
        reader.join(timeout=15)  # the busy timeout is 30 s: a GET that waited for the lock would still hang
        assert not reader.is_alive(), "a GET request waited for SQLite's writer lock"
        assert answers == {"image": 200, "statistics": 200}

        # A writing request does wait for the lock (and goes through once it is released).
        written: dict[str, int] = {}
        writer = threading.Thread(target=lambda: written.setdefault(
            "next", env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).status_code),
            daemon=True)
        writer.start()
        writer.join(timeout=1.0)
        assert writer.is_alive() and not written
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    writer.join(timeout=30)
    assert written == {"next": 200}
