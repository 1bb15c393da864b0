"""A short-lived, per-process cache of token -> user lookups.

Every request is authenticated; reading the user's row each time was two of the annotator cycle's
statements. Entries live `ttl_s` seconds and are dropped as soon as this process changes the user (see
`watch_user_changes`), so a revoked token (password, role or active flag changed: the token version is
bumped) stops working at once in the process that made the change and within `ttl_s` in the others
(other server workers, the CLI). A token newer than the cached row makes the row be read again.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from sqlalchemy import event
from sqlalchemy.orm import Session, sessionmaker

from backend.models.users import User
from backend.services.accounts.users import Principal
from backend.services.transactions import after_commit


class AuthCache:
    def __init__(self, ttl_s: float, clock: Callable[[], float] = time.monotonic, max_entries: int = 10_000) -> None:
        self.ttl_s = ttl_s
        self.clock = clock
        self.max_entries = max_entries
        self._entries: dict[int, tuple[Principal, float]] = {}
        self._generations: dict[int, int] = {}
        self._lock = threading.Lock()  # readers are lock-free (one dict lookup); writers serialise

    def get(self, user_id: int) -> Principal | None:
        """The cached user if the entry is younger than the TTL."""
        entry = self._entries.get(user_id)
        if entry is None or self.clock() - entry[1] >= self.ttl_s:
            return None
        return entry[0]

    def generation(self, user_id: int) -> int:
        """Read before loading the row; `put` ignores the row if the user was invalidated meanwhile."""
        return self._generations.get(user_id, 0)

    def put(self, principal: Principal, generation: int) -> None:
        if self.ttl_s <= 0:
            return
        with self._lock:
            if self._generations.get(principal.id, 0) != generation:
                return  # changed while we read it: this row may be stale
            if len(self._entries) >= self.max_entries:
                self._entries.clear()  # crude but bounded; entries are cheap to read again
            self._entries[principal.id] = (principal, self.clock())

    def invalidate(self, user_id: int) -> None:
        with self._lock:
            self._entries.pop(user_id, None)
            self._generations[user_id] = self._generations.get(user_id, 0) + 1


def watch_user_changes(session_factory: sessionmaker[Session], cache: AuthCache) -> None:
    """Invalidate a user's entry when a session of this factory flushes a change to (or deletes) that user,
    and again after the commit, so that a lookup racing the change cannot keep the old row."""

    @event.listens_for(session_factory, "after_flush")
    def _after_flush(session: Session, _context: Any) -> None:
        changed = [obj.id for obj in (*session.dirty, *session.deleted) if isinstance(obj, User)]
        for user_id in changed:
            cache.invalidate(user_id)
            after_commit(session, lambda user_id=user_id: cache.invalidate(user_id))
