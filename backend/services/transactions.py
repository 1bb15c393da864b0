"""Work that must wait for the transaction to commit (e.g. queueing a Celery task that reads the rows)."""

from __future__ import annotations

from collections.abc import Callable

from sqlalchemy.orm import Session

_KEY = "after_commit"


def after_commit(session: Session, callback: Callable[[], None]) -> None:
    """Run `callback` once the current transaction commits; dropped on rollback."""
    session.info.setdefault(_KEY, []).append(callback)


def run_after_commit(session: Session) -> None:
    callbacks = session.info.pop(_KEY, [])
    for callback in callbacks:
        callback()


def discard_after_commit(session: Session) -> None:
    session.info.pop(_KEY, None)
