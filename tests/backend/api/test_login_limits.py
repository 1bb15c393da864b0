"""Login limits (issue #13, defect 9): failures per account and per client address, bounded password hashing,
429 with Retry-After. The limiter's clock is injected: time moves without sleeping."""

from __future__ import annotations

import pytest

from backend.models.enums import Role
from backend.services.accounts import users
from backend.services.accounts.login_limits import LoginLimiter, LoginPolicy

PASSWORD = "correct horse battery"  # tests/backend/conftest.py
WINDOW_S = 900.0


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def limited(sqlite_env):
    """The app with a limiter on a fake clock: 3 failures per account, 6 per address."""
    clock = FakeClock()
    policy = LoginPolicy(max_failures_per_account=3, max_failures_per_address=6, window_s=WINDOW_S,
                         max_concurrent_hashes=2, hash_wait_s=0.0)
    sqlite_env.client.app.state.login_limiter = LoginLimiter(policy, clock=clock)
    return sqlite_env, clock


def _login(env, email: str, password: str):
    return env.client.post("/api/auth/token", data={"username": email, "password": password})


def test_after_too_many_failures_even_the_right_password_waits(limited):
    env, clock = limited
    email = "ann@example.org"
    for _ in range(3):
        assert _login(env, email, "wrong password").status_code == 401
    refused = _login(env, email.upper(), PASSWORD)  # the same account, however it is spelled
    assert refused.status_code == 429, refused.text
    assert "this account" in refused.json()["detail"]
    assert int(refused.headers["retry-after"]) == WINDOW_S
    clock.now += 600
    assert int(_login(env, email, PASSWORD).headers["retry-after"]) == WINDOW_S - 600
    clock.now += 300
    assert _login(env, email, PASSWORD).status_code == 200
    assert _login(env, "rev@example.org", PASSWORD).status_code == 200  # other accounts were never locked


def test_a_locked_account_costs_no_password_hashing(limited, monkeypatch):
    env, _clock = limited
    for _ in range(3):
        _login(env, "ann@example.org", "wrong password")
    calls = []
    monkeypatch.setattr(users, "authenticate", lambda *a: calls.append(a))
    assert _login(env, "ann@example.org", PASSWORD).status_code == 429
    assert calls == []


def test_a_success_clears_the_accounts_failures(limited):
    env, _clock = limited
    for _ in range(2):
        assert _login(env, "ann@example.org", "wrong password").status_code == 401
    assert _login(env, "ann@example.org", PASSWORD).status_code == 200
    for _ in range(2):
        assert _login(env, "ann@example.org", "wrong password").status_code == 401
    assert _login(env, "ann@example.org", PASSWORD).status_code == 200


def test_failures_from_one_address_across_accounts_are_limited(limited):
    """Guessing many accounts (known or not) from one address."""
    env, clock = limited
    for i in range(6):
        assert _login(env, f"nobody{i}@example.org", "guess").status_code == 401
    refused = _login(env, "admin@example.org", PASSWORD)
    assert refused.status_code == 429 and "your address" in refused.json()["detail"]
    assert int(refused.headers["retry-after"]) == WINDOW_S
    clock.now += WINDOW_S
    assert _login(env, "admin@example.org", PASSWORD).status_code == 200


def test_password_hashing_is_bounded(limited):
    env, _clock = limited
    limiter = env.client.app.state.login_limiter
    assert limiter.hash_slots.acquire(timeout=0) and limiter.hash_slots.acquire(timeout=0)  # both slots busy
    try:
        busy = _login(env, "ann@example.org", PASSWORD)
        assert busy.status_code == 429 and "busy" in busy.json()["detail"] and busy.headers["retry-after"]
    finally:
        limiter.hash_slots.release()
        limiter.hash_slots.release()
    assert _login(env, "ann@example.org", PASSWORD).status_code == 200
    assert _login(env, "ann@example.org", "wrong password").status_code == 401  # busy answers counted no failure


def test_limits_come_from_the_settings(env_with, sqlite_url, tmp_path):
    env = env_with(sqlite_url, tmp_path, login_max_failures_per_account=1, login_max_concurrent_hashes=3)
    policy = env.client.app.state.login_limiter.policy
    assert (policy.max_failures_per_account, policy.max_concurrent_hashes) == (1, 3)
    assert _login(env, "ann@example.org", "wrong password").status_code == 401
    assert _login(env, "ann@example.org", PASSWORD).status_code == 429
    assert env.client.get("/api/auth/me", headers=env.headers(Role.annotator)).status_code == 200  # tokens still work


def _limited_app(env_with, sqlite_url, tmp_path, **overrides):
    env = env_with(sqlite_url, tmp_path, **overrides)
    policy = LoginPolicy(max_failures_per_account=3, max_failures_per_address=6, window_s=WINDOW_S,
                         max_concurrent_hashes=2, hash_wait_s=0.0)
    env.client.app.state.login_limiter = LoginLimiter(policy, clock=FakeClock())
    return env.client.app


def _guess_from(app, peer: str, forwarded_for: str, i: int) -> int:
    from fastapi.testclient import TestClient

    with TestClient(app, client=(peer, 40000)) as client:
        return client.post("/api/auth/token", data={"username": f"nobody{i}@example.org", "password": "guess"},
                           headers={"X-Forwarded-For": forwarded_for}).status_code


def test_forwarded_for_counts_only_from_a_configured_proxy(env_with, sqlite_url, tmp_path):
    """Issue 38 item 12: a spoofed X-Forwarded-For from a peer that is not a configured proxy (localhost included)
    does not give each made-up address fresh tries; from a configured proxy it names the client."""
    app = _limited_app(env_with, sqlite_url, tmp_path / "a")
    codes = [_guess_from(app, "127.0.0.1", f"203.0.113.{i}", i) for i in range(7)]
    assert codes == [401] * 6 + [429]
    proxied = _limited_app(env_with, sqlite_url, tmp_path / "b", trusted_proxies=["127.0.0.1"])
    assert [_guess_from(proxied, "127.0.0.1", f"203.0.113.{i}", i) for i in range(7)] == [401] * 7
    assert [_guess_from(proxied, "10.1.1.1", f"203.0.113.{i}", i) for i in range(7)] == [401] * 6 + [429]


def test_serve_leaves_uvicorns_forwarded_headers_off(monkeypatch):
    """uvicorn's default takes X-Forwarded-For from any localhost peer; `handloop serve` turns that off (the app
    reads it only from HANDLOOP_TRUSTED_PROXIES)."""
    import uvicorn
    from typer.testing import CliRunner

    from backend.cli.main import app as cli

    seen: dict = {}
    monkeypatch.setattr(uvicorn, "run", lambda *args, **kwargs: seen.update(kwargs))
    result = CliRunner().invoke(cli, ["serve", "--no-migrate"])
    assert result.exit_code == 0, result.output
    assert seen["proxy_headers"] is False
