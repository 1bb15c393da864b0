"""The annotators' hot path (backend.api.hot_path): it answers plain requests itself, and every other request gets
exactly FastAPI's answer, with nothing written by the attempt."""

from __future__ import annotations

import asyncio
import shutil

import pytest
from sqlalchemy import text

from backend.api import hot_path
from backend.api.hot_path import AnnotatorHotPath, _replay, submit_sample_id
from backend.models.enums import Role

TABLES = ("submissions", "clicks", "jobs", "audit_events")


@pytest.fixture
def answered(monkeypatch):
    """How many requests the hot path answered itself, per route."""
    counts = {"next": 0, "submit": 0}

    def counting(name, real):
        def call(*args, **kwargs):
            counts[name] += 1
            return real(*args, **kwargs)
        return call

    monkeypatch.setattr(hot_path, "next_response", counting("next", hot_path.next_response))
    monkeypatch.setattr(hot_path, "submit_response", counting("submit", hot_path.submit_response))
    return counts


def _without_hot_path(app):
    app.user_middleware = [m for m in app.user_middleware if m.cls is not AnnotatorHotPath]
    return app


def test_plain_requests_are_answered_by_the_hot_path(env, h, answered):
    ids = h.seed(env, frames=2, cameras=2)
    headers = env.headers(Role.annotator)
    first = env.client.post("/api/annotate/next", headers=headers)  # the user read in the route's thread
    assert first.status_code == 200 and answered == {"next": 1, "submit": 0}
    again = env.client.post("/api/annotate/next", headers=headers)  # from the cache
    assert again.status_code == 200 and answered["next"] == 2
    assert again.json()["sample_id"] == first.json()["sample_id"] == ids[0]
    assert again.json()["lease_token"] == first.json()["lease_token"]
    assert again.headers["content-security-policy"] == first.headers["content-security-policy"]
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(again.json()),
                               headers=headers)
    assert response.status_code == 201 and answered["submit"] == 1
    assert response.json()["n_clicks"] == 12 and response.json()["duplicate"] is False
    assert env.queue.enqueued == [(response.json()["fit_job_id"], "fit")]
    assert h.count(env, "clicks") == 12


def test_the_hot_path_is_not_used_by_other_roles_routes_or_queries(env, h, answered):
    h.seed(env, frames=2, cameras=1)
    headers = env.headers(Role.annotator)
    assert env.client.post("/api/annotate/next?x=1", headers=headers).status_code == 200
    assert env.client.post("/api/review/next", headers=env.headers(Role.reviewer)).status_code in (200, 204)
    assert answered == {"next": 0, "submit": 0}


# Requests the hot path hands on (after trying some of them): the answer must be FastAPI's, byte for byte.
def _cases(task: dict, h) -> list[tuple[str, str, dict | bytes, dict]]:
    sample = task["sample_id"]
    url = f"/api/annotate/samples/{sample}/submissions"
    bad_click = h.body(task, client_id="case-bad-click")
    bad_click["clicks"][0]["x"] = "12"
    outside = h.body(task, client_id="case-outside")
    outside["clicks"][0]["x"] = 1e5
    return [
        ("string coordinate", url, bad_click, {}),
        ("click outside the image", url, outside, {}),
        ("stale lease token", url, h.body(task, client_id="case-stale", lease_token="not-the-token"), {}),
        ("unknown field", url, {**h.body(task, client_id="case-extra"), "extra": 1}, {}),
        ("not JSON", url, b"{not json", {"content-type": "application/json"}),
        ("text/plain", url, b"{}", {"content-type": "text/plain"}),
        ("id beyond range", "/api/annotate/samples/99999999999/submissions", h.body(task, client_id="case-big"), {}),
        ("sample not leased", "/api/annotate/samples/2147483647/submissions", h.body(task, client_id="case-none"), {}),
        ("empty body", url, b"", {"content-type": "application/json"}),
        # last: FastAPI reads "01" as 1, so this one is accepted (by the route, not the hot path)
        ("zero-padded id", f"/api/annotate/samples/0{sample}/submissions", h.body(task, client_id="case-pad"), {}),
    ]


def test_requests_it_hands_on_get_fastapis_answer_and_write_nothing(sqlite_url, tmp_path, env_with, h, answered):
    plain_path = tmp_path / "plain.sqlite3"
    shutil.copyfile(sqlite_url.removeprefix("sqlite:///"), plain_path)
    hot = env_with(sqlite_url, tmp_path / "hot")
    plain = env_with(f"sqlite:///{plain_path}", tmp_path / "plain")
    _without_hot_path(plain.client.app)
    plain.client.app.middleware_stack = plain.client.app.build_middleware_stack()
    for e in (hot, plain):
        h.seed(e, frames=2, cameras=2)
    tasks = [h.next_task(e) for e in (hot, plain)]
    tasks = [h.next_task(e) for e in (hot, plain)]  # the second: the hot path's, with the user cached
    assert tasks[0]["sample_id"] == tasks[1]["sample_id"]
    before = answered["submit"]
    counts = {t: h.count(hot, t) for t in TABLES}
    for (name, url, body, headers), (_, url2, body2, headers2) in zip(_cases(tasks[0], h), _cases(tasks[1], h),
                                                                        strict=True):
        responses = []
        for e, u, b, extra in ((hot, url, body, headers), (plain, url2, body2, headers2)):
            kwargs = {"content": b} if isinstance(b, bytes) else {"json": b}
            responses.append(e.client.post(u, headers={**e.headers(Role.annotator), **extra}, **kwargs))
        assert responses[0].status_code == responses[1].status_code, name
        assert responses[0].headers.get("content-type") == responses[1].headers.get("content-type"), name
        if name != "zero-padded id":  # (its answer holds the time it was written)
            assert responses[0].content == responses[1].content, name
            assert responses[0].status_code >= 400, name
            assert {t: h.count(hot, t) for t in TABLES} == counts, name
    # tried, failed in the service, handed on: the click outside the image, the stale token, the unleased sample
    assert answered["submit"] == before + 3
    assert responses[0].status_code == 201 and h.count(hot, "clicks") == counts["clicks"] + 12


def test_a_failing_attempt_is_answered_by_the_route(env, h, monkeypatch):
    ids = h.seed(env, frames=1, cameras=1)
    headers = env.headers(Role.annotator)
    h.next_task(env)
    task = h.next_task(env)
    calls = []

    def broken(*args, **kwargs):
        calls.append(args)
        raise RuntimeError("the hot path's own failure")

    monkeypatch.setattr(hot_path, "submit_response", broken)
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task), headers=headers)
    assert calls and response.status_code == 201  # FastAPI's route did the work
    with env.session() as s:
        assert s.execute(text("SELECT count(*) FROM submissions")).scalar() == 1


def test_a_revoked_token_is_refused_even_when_cached(env, h, answered):
    h.seed(env, frames=1, cameras=1)
    h.next_task(env)
    with env.session() as s, s.begin():
        s.execute(text("UPDATE users SET token_version = token_version + 1 WHERE id = :i"),
                  {"i": env.user_ids[Role.annotator]})
    env.app_cache().invalidate(env.user_ids[Role.annotator])  # as the process that revoked it does
    response = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator))
    assert response.status_code == 401 and answered["next"] == 1  # only the first request's work ran


def test_a_deactivated_user_in_another_process_is_refused_once_the_cache_lapses(env, h, answered):
    h.seed(env, frames=1, cameras=1)
    h.next_task(env)
    with env.session() as s, s.begin():  # another process's change: this process's cache keeps the row a while
        s.execute(text("UPDATE users SET is_active = false WHERE id = :i"), {"i": env.user_ids[Role.annotator]})
    env.app_cache().clock = lambda: float("inf")  # the entry has lapsed
    response = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator))
    assert response.status_code == 401 and "deactivated" in response.json()["detail"] and answered["next"] == 1


@pytest.mark.parametrize(("path", "expected"), [
    ("/api/annotate/samples/12/submissions", 12), ("/api/annotate/samples/2147483647/submissions", 2147483647),
    ("/api/annotate/samples/2147483648/submissions", None), ("/api/annotate/samples/012/submissions", None),
    ("/api/annotate/samples/0/submissions", None), ("/api/annotate/samples/-1/submissions", None),
    ("/api/annotate/samples/１２/submissions", None), ("/api/annotate/samples//submissions", None),
    ("/api/annotate/samples/12/submissions/x", None), ("/api/review/samples/12/submissions", None)])
def test_submit_sample_id(path, expected):
    assert submit_sample_id(path) == expected


def test_replay_gives_the_body_then_what_follows():
    async def receive():
        return {"type": "http.disconnect"}

    async def run(body, disconnected):
        replayed = _replay(body, disconnected, receive)
        return [await replayed() for _ in range(3)]

    whole = asyncio.run(run(b"abc", False))
    assert whole[0] == {"type": "http.request", "body": b"abc", "more_body": False}
    assert whole[1:] == [{"type": "http.disconnect"}] * 2
    cut = asyncio.run(run(b"ab", True))
    assert cut[0] == {"type": "http.request", "body": b"ab", "more_body": True} and cut[1]["type"] == "http.disconnect"


def test_it_sits_inside_the_body_limit_and_the_security_headers(sqlite_env):
    from backend.api.limits import BodySizeLimit
    from backend.api.security_headers import SecurityHeaders

    outermost_first = [m.cls for m in sqlite_env.client.app.user_middleware]
    assert outermost_first == [SecurityHeaders, BodySizeLimit, AnnotatorHotPath]


def test_the_users_row_is_read_without_a_transaction_on_postgresql(env, h, monkeypatch):
    """One round trip for a crowd annotator's lapsed cache entry: no BEGIN before the SELECT, no ROLLBACK after."""
    from backend.api import deps

    levels = []
    real = deps.load_principal

    def spy(session, user_id):
        levels.append(session.connection().get_execution_options().get("isolation_level"))
        return real(session, user_id)

    monkeypatch.setattr(deps, "load_principal", spy)
    h.seed(env, frames=1, cameras=1)
    h.next_task(env)
    postgres = env.settings.resolved_database_url.startswith("postgresql")
    assert levels and all((level == "AUTOCOMMIT") == postgres for level in levels)
