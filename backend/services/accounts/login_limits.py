"""Limits on logins: failed attempts per account and per client address in a sliding window, and a bound on
concurrent password hashing (each Argon2 check costs ~260 ms of CPU and 64 MiB).

A locked account or address is refused before its password is hashed, so an attacker cannot load the server
with guesses and cannot keep guessing one account; a success clears the account's failures (not the
address's). State is per server process: with N server workers an attacker gets at most N times the limits
(docs/api.md). The clock is injected, so tests move time instead of sleeping.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from backend.services.errors import RateLimitedError
from backend.settings import Settings

MAX_TRACKED_KEYS = 100_000  # accounts + addresses remembered; beyond it the stalest are forgotten


@dataclass(frozen=True)
class LoginPolicy:
    max_failures_per_account: int
    max_failures_per_address: int
    window_s: float
    max_concurrent_hashes: int
    hash_wait_s: float

    @classmethod
    def from_settings(cls, settings: Settings) -> LoginPolicy:
        return cls(settings.login_max_failures_per_account, settings.login_max_failures_per_address,
                   settings.login_failure_window_s, settings.login_max_concurrent_hashes, settings.login_hash_wait_s)


class _FailureLog:
    """Failure times (clock seconds) per key, oldest first, kept for one window."""

    def __init__(self, limit: int, window_s: float) -> None:
        self.limit, self.window_s = limit, window_s
        self._times: dict[str, deque[float]] = {}

    def _recent(self, key: str, now: float) -> deque[float] | None:
        times = self._times.get(key)
        if times is None:
            return None
        while times and times[0] <= now - self.window_s:
            times.popleft()
        if not times:
            del self._times[key]
            return None
        return times

    def retry_after_s(self, key: str, now: float) -> float | None:
        """Seconds until `key` may try again, or None when it is under its limit."""
        times = self._recent(key, now)
        if times is None or len(times) < self.limit:
            return None
        return times[-self.limit] + self.window_s - now  # when the limit-th newest failure leaves the window

    def add(self, key: str, now: float) -> None:
        times = self._recent(key, now)
        if times is None:
            if len(self._times) >= MAX_TRACKED_KEYS:
                self._forget_stalest()
            times = self._times[key] = deque(maxlen=self.limit)
        times.append(now)

    def clear(self, key: str) -> None:
        self._times.pop(key, None)

    def _forget_stalest(self) -> None:
        stalest = sorted(self._times, key=lambda k: self._times[k][-1])[: MAX_TRACKED_KEYS // 2]
        for key in stalest:
            del self._times[key]


class LoginLimiter:
    def __init__(self, policy: LoginPolicy, clock: Callable[[], float] = time.monotonic) -> None:
        self.policy = policy
        self.clock = clock
        self._accounts = _FailureLog(policy.max_failures_per_account, policy.window_s)
        self._addresses = _FailureLog(policy.max_failures_per_address, policy.window_s)
        self._lock = threading.Lock()
        self.hash_slots = threading.BoundedSemaphore(policy.max_concurrent_hashes)

    def check(self, account: str, address: str) -> None:
        """RateLimitedError (with Retry-After) if the account or the address has used up its failures."""
        with self._lock:
            now = self.clock()
            by_account = self._accounts.retry_after_s(account, now)
            by_address = self._addresses.retry_after_s(address, now)
        if by_account is not None:
            raise RateLimitedError(f"too many failed logins for this account; try again in {_whole(by_account)} s",
                                   _whole(by_account))
        if by_address is not None:
            raise RateLimitedError(f"too many failed logins from your address; try again in {_whole(by_address)} s",
                                   _whole(by_address))

    def failed(self, account: str, address: str) -> None:
        with self._lock:
            now = self.clock()
            self._accounts.add(account, now)
            self._addresses.add(address, now)

    def succeeded(self, account: str) -> None:
        with self._lock:
            self._accounts.clear(account)

    def account_lock_s(self, account: str) -> float | None:
        """Seconds until a locked account may try again (None: not locked), in this server process."""
        with self._lock:
            return self._accounts.retry_after_s(account, self.clock())

    def unlock(self, account: str) -> bool:
        """Forget the account's failures (an admin's unlock); True when it was locked. The addresses' failures
        stay: an address that guessed stays limited."""
        with self._lock:
            was_locked = self._accounts.retry_after_s(account, self.clock()) is not None
            self._accounts.clear(account)
        return was_locked

    @contextmanager
    def hashing(self) -> Iterator[None]:
        """Hold one of the password-hashing slots; RateLimitedError if none frees up within `hash_wait_s`."""
        if not self.hash_slots.acquire(timeout=self.policy.hash_wait_s):
            raise RateLimitedError("the server is busy checking other logins; try again in a few seconds", 2)
        try:
            yield
        finally:
            self.hash_slots.release()


def _whole(seconds: float) -> int:
    return max(1, math.ceil(seconds))
