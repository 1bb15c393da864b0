"""The annotators' hot path (backend.api.hot_path): it answers plain requests itself, and every other request gets
exactly FastAPI's answer, with nothing written by the attempt."""

from __future__ import annotations

import asyncio
import logging
import os
import shutil
import uuid

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.exc import OperationalError

from backend.api import hot_path
from backend.api.hot_path import AnnotatorHotPath, _replay, submit_sample_id
from backend.api.routes import annotate
from backend.models.enums import Role
from backend.services.accounts.security import create_token

TABLES = ("submissions", "clicks", "jobs", "audit_events", "annotation_flags")
PG_ADMIN_URL = os.environ.get("HANDLOOP_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/postgres")


def _count_calls(monkeypatch, module) -> dict[str, int]:
    """Calls of `module`'s next_response and submit_response, counted per route."""
    counts = {"next": 0, "submit": 0}

    def counting(name, real):
        def call(*args, **kwargs):
            counts[name] += 1
            return real(*args, **kwargs)
        return call

    monkeypatch.setattr(module, "next_response", counting("next", module.next_response))
    monkeypatch.setattr(module, "submit_response", counting("submit", module.submit_response))
    return counts


@pytest.fixture
def answered(monkeypatch):
    """How many requests the hot path answered itself, per route."""
    return _count_calls(monkeypatch, hot_path)


@pytest.fixture
def by_the_route(monkeypatch):
    """How many requests FastAPI's routes ran the work of, per route (the hot path's own calls not counted)."""
    return _count_calls(monkeypatch, annotate)


@pytest.fixture
def handed_on(monkeypatch):
    """The requests the hot path handed on to FastAPI's route (their bodies replayed), in order."""
    calls = []
    real = hot_path._replay

    def replay(*args, **kwargs):
        calls.append(args[0])
        return real(*args, **kwargs)

    monkeypatch.setattr(hot_path, "_replay", replay)
    return calls


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def twin_urls(request, tmp_path):
    """Two databases alike, fresh from the test template, on either backend: one per path."""
    if request.param == "sqlite":
        first = request.getfixturevalue("sqlite_url")
        second = tmp_path / "plain.sqlite3"
        shutil.copyfile(first.removeprefix("sqlite:///"), second)
        yield first, f"sqlite:///{second}"
        return
    first = request.getfixturevalue("pg_url")
    template = request.getfixturevalue("pg_template")
    admin = create_engine(PG_ADMIN_URL, isolation_level="AUTOCOMMIT")
    name = f"handloop_test_{uuid.uuid4().hex[:10]}"
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}" TEMPLATE "{template}"'))
    try:
        yield first, PG_ADMIN_URL.rsplit("/", 1)[0] + f"/{name}"
    finally:
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def _without_hot_path(app):
    app.user_middleware = [m for m in app.user_middleware if m.cls is not AnnotatorHotPath]
    app.middleware_stack = app.build_middleware_stack()
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


# The same requests on both paths: the answer must be the route's, byte for byte, and a refusal writes nothing.
# (name, path, body, extra headers, who: the role whose token is sent, "revoked" a token newer than the user's row,
# "deactivated" the admin's, deactivated; answered by: "hot" the hot path itself, "route" FastAPI's route after the
# hot path read the request and handed it on, "passed" FastAPI's route, the hot path not having taken the request)
def _cases(task: dict, h) -> list[tuple[str, str, dict | bytes, dict, str, str]]:
    sample = task["sample_id"]
    url = f"/api/annotate/samples/{sample}/submissions"
    bad_click = h.body(task, client_id="case-bad-click")
    bad_click["clicks"][0]["x"] = "12"
    outside = h.body(task, client_id="case-outside")
    outside["clicks"][0]["x"] = 1e5
    foreign_view = h.body(task, client_id="case-foreign-view")
    foreign_view["clicks"][0]["view_id"] = 2147483647
    no_hand_twice = h.body(task, client_id="case-no-hand-twice", no_hand_views=[task["views"][0]["id"]] * 2)
    valid = h.body(task, client_id="case-valid")
    return [
        # refused by the one checked service call (submissions.submit), or by the user's checks before it
        ("click outside the image", url, outside, {}, "annotator", "hot"),
        ("click in a view not of the sample", url, foreign_view, {}, "annotator", "hot"),
        ("no-hand view given twice", url, no_hand_twice, {}, "annotator", "hot"),
        ("stale lease token", url, h.body(task, client_id="case-stale", lease_token="not-the-token"), {},
         "annotator", "hot"),
        ("sample not leased", "/api/annotate/samples/2147483647/submissions", h.body(task, client_id="case-none"),
         {}, "annotator", "hot"),
        ("lease held by another", url, h.body(task, client_id="case-other"), {}, "reviewer", "hot"),
        ("revoked token", url, valid, {}, "revoked", "hot"),
        ("deactivated account", url, valid, {}, "deactivated", "hot"),
        ("next with a revoked token", "/api/annotate/next", b"", {}, "revoked", "hot"),
        ("next for a deactivated account", "/api/annotate/next", b"", {}, "deactivated", "hot"),
        # not plain: FastAPI words the answer (a schema's 422, the 401 of a missing or unreadable token)
        ("string coordinate", url, bad_click, {}, "annotator", "route"),
        ("unknown field", url, {**h.body(task, client_id="case-extra"), "extra": 1}, {}, "annotator", "route"),
        ("not JSON", url, b"{not json", {"content-type": "application/json"}, "annotator", "route"),
        ("text/plain", url, b"{}", {"content-type": "text/plain"}, "annotator", "route"),
        ("id beyond range", "/api/annotate/samples/99999999999/submissions", h.body(task, client_id="case-big"), {},
         "annotator", "passed"),
        ("empty body", url, b"", {"content-type": "application/json"}, "annotator", "route"),
        ("no token", url, valid, {}, "nobody", "passed"),
        ("revoked token, body not JSON", url, b"{not json", {"content-type": "application/json"}, "revoked",
         "route"),
        # last: FastAPI reads "01" as 1, so this one is accepted (by the route, not the hot path)
        ("zero-padded id", f"/api/annotate/samples/0{sample}/submissions", h.body(task, client_id="case-pad"), {},
         "annotator", "passed"),
    ]


def _headers(env, who: str) -> dict[str, str]:
    if who == "nobody":
        return {}
    if who == "revoked":  # a token of a version the user's row does not have (the row's was bumped since)
        token = create_token(env.settings.secret_key, env.user_ids[Role.annotator], 7, 3600)
        return {"Authorization": f"Bearer {token}"}
    return env.headers(Role.admin if who == "deactivated" else Role(who))


def test_both_paths_give_the_same_answers_and_refusals_write_nothing(twin_urls, tmp_path, env_with, h, answered,
                                                                     handed_on):
    hot = env_with(twin_urls[0], tmp_path / "hot")
    plain = env_with(twin_urls[1], tmp_path / "plain")
    _without_hot_path(plain.client.app)
    for e in (hot, plain):
        h.seed(e, frames=2, cameras=2)
        with e.session() as s, s.begin():
            s.execute(text("UPDATE users SET is_active = false WHERE id = :i"), {"i": e.user_ids[Role.admin]})
    tasks = [h.next_task(e) for e in (hot, plain)]
    tasks = [h.next_task(e) for e in (hot, plain)]  # the second: the hot path's, with the user cached
    assert tasks[0]["sample_id"] == tasks[1]["sample_id"]
    before, counts = dict(answered), {t: h.count(hot, t) for t in TABLES}
    cases = list(zip(_cases(tasks[0], h), _cases(tasks[1], h), strict=True))
    for (name, url, body, headers, who, by), (_, url2, body2, headers2, _, _) in cases:
        responses, handed_before = [], len(handed_on)
        for e, u, b, extra in ((hot, url, body, headers), (plain, url2, body2, headers2)):
            kwargs = {"content": b} if isinstance(b, bytes) else {"json": b}
            responses.append(e.client.post(u, headers={**_headers(e, who), **extra}, **kwargs))
        assert responses[0].status_code == responses[1].status_code, name
        for header in ("content-type", "www-authenticate", "retry-after"):
            assert responses[0].headers.get(header) == responses[1].headers.get(header), (name, header)
        assert len(handed_on) - handed_before == (by == "route"), (name, "handed on", by)
        if name != "zero-padded id":  # (its answer holds the time it was written)
            assert responses[0].content == responses[1].content, name
            assert responses[0].status_code >= 400, name
            assert {t: h.count(hot, t) for t in TABLES} == counts, name
    # the six service refusals ran the work once, on the hot path, which answered them; the user checks come first
    assert answered["submit"] == before["submit"] + 6 and answered["next"] == before["next"]
    assert responses[0].status_code == 201 and h.count(hot, "clicks") == counts["clicks"] + 12


def test_a_failing_attempt_is_logged_and_answered_by_the_route(env, h, monkeypatch, caplog):
    ids = h.seed(env, frames=1, cameras=1)
    headers = env.headers(Role.annotator)
    h.next_task(env)
    task = h.next_task(env)
    calls = []

    def broken(*args, **kwargs):
        calls.append(args)
        raise RuntimeError("the hot path's own failure")

    monkeypatch.setattr(hot_path, "submit_response", broken)
    with caplog.at_level(logging.ERROR, logger="backend.api.hot_path"):
        response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task),
                                   headers=headers)
    assert calls and response.status_code == 201  # FastAPI's route did the work
    with env.session() as s:
        assert s.execute(text("SELECT count(*) FROM submissions")).scalar() == 1
    failures = [r for r in caplog.records if r.name == "backend.api.hot_path"]  # said, with its reason
    assert len(failures) == 1 and "FastAPI's route answers it" in failures[0].getMessage()
    assert failures[0].exc_info and "the hot path's own failure" in str(failures[0].exc_info[1])


def test_a_database_failure_of_the_attempt_is_logged_and_the_route_answers(env, h, monkeypatch, caplog,
                                                                           by_the_route):
    ids = h.seed(env, frames=1, cameras=1)
    h.next_task(env)
    task = h.next_task(env)

    def busy(*args, **kwargs):
        raise OperationalError("SELECT 1", {}, Exception("database is locked (as a test makes it)"))

    monkeypatch.setattr(hot_path, "submit_response", busy)
    with caplog.at_level(logging.WARNING, logger="backend.api.hot_path"):
        response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task),
                                   headers=env.headers(Role.annotator))
    assert response.status_code == 201 and by_the_route["submit"] == 1
    warnings = [r.getMessage() for r in caplog.records if r.name == "backend.api.hot_path"]
    assert len(warnings) == 1 and "database is locked (as a test makes it)" in warnings[0], warnings


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
