"""The token -> user cache: entries expire, user changes in this process drop them at once, and a
revocation made elsewhere (another server process) takes effect within the TTL. Clocks are fakes."""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import text

from backend.models.enums import Role
from backend.services.accounts.auth_cache import AuthCache
from backend.services.accounts.users import Principal


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _principal(version: int = 0) -> Principal:
    return Principal(7, "a@x.org", "", "annotator", True, version, datetime(2026, 1, 1, tzinfo=UTC))


def test_entries_expire_after_the_ttl():
    clock = FakeClock()
    cache = AuthCache(2.0, clock=clock)
    cache.put(_principal(), cache.generation(7))
    assert cache.get(7) == _principal()
    clock.now += 1.9
    assert cache.get(7) is not None
    clock.now += 0.2
    assert cache.get(7) is None


def test_a_row_read_before_an_invalidation_is_not_cached():
    cache = AuthCache(2.0, clock=FakeClock())
    generation = cache.generation(7)  # a request starts reading the row ...
    cache.invalidate(7)  # ... while another request changes the user
    cache.put(_principal(), generation)
    assert cache.get(7) is None
    cache.put(_principal(1), cache.generation(7))
    assert cache.get(7) == _principal(1)


def test_zero_ttl_disables_the_cache():
    cache = AuthCache(0.0, clock=FakeClock())
    cache.put(_principal(), cache.generation(7))
    assert cache.get(7) is None


def _me(env, headers):
    return env.client.get("/api/auth/me", headers=headers)


def test_change_through_the_api_revokes_at_once(sqlite_env):
    env = sqlite_env
    uid = env.user_ids[Role.annotator]
    headers = env.headers(Role.annotator)
    assert _me(env, headers).status_code == 200  # now cached
    assert env.app_cache().get(uid) is not None
    response = env.client.patch(f"/api/admin/users/{uid}", headers=env.headers(Role.admin),
                                json={"role": "reviewer"})
    assert response.status_code == 200
    assert env.app_cache().get(uid) is None
    refused = _me(env, headers)
    assert refused.status_code == 401 and "revoked" in refused.json()["detail"]


def test_revocation_by_another_process_takes_effect_within_the_ttl(sqlite_env):
    env = sqlite_env
    clock = FakeClock()
    env.app_cache().clock = clock
    uid = env.user_ids[Role.annotator]
    headers = env.headers(Role.annotator)
    assert _me(env, headers).status_code == 200
    with env.session() as s, s.begin():  # as another server process or the CLI would: no event in this one
        s.execute(text("UPDATE users SET token_version = token_version + 1, is_active = false WHERE id = :i"),
                  {"i": uid})
    clock.now += env.settings.auth_cache_seconds / 2
    assert _me(env, headers).status_code == 200  # the documented window
    clock.now += env.settings.auth_cache_seconds
    assert _me(env, headers).status_code == 401


def test_a_newer_token_reads_the_row_again(sqlite_env):
    from backend.services.accounts.security import create_token

    env = sqlite_env
    uid = env.user_ids[Role.annotator]
    assert _me(env, env.headers(Role.annotator)).status_code == 200  # version 0 cached
    with env.session() as s, s.begin():
        s.execute(text("UPDATE users SET token_version = 1 WHERE id = :i"), {"i": uid})
    newer = {"Authorization": f"Bearer {create_token(env.settings.secret_key, uid, 1, 3600)}"}
    assert _me(env, newer).status_code == 200
    assert _me(env, env.headers(Role.annotator)).status_code == 401  # the old token is refused from the new row
