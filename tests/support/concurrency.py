"""Run one call from several threads released together (a barrier), for races on the database."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def all_at_once(n: int, call: Callable[[Callable[[], None]], T], join_s: float = 60.0) -> list[T]:
    """Results of `call(release)` run in `n` threads; each call invokes `release()` (the barrier) once it is
    ready to race. Raises AssertionError naming the exceptions if any thread raised."""
    barrier = threading.Barrier(n)
    results: list[T] = []
    errors: list[BaseException] = []

    def worker() -> None:
        try:
            results.append(call(barrier.wait))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=worker) for _ in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(join_s)
    assert not errors, errors
    return results
