"""Bad input at the edge (issue #13): out-of-range path ids and loosely typed bodies are 422s that name the
field, and write nothing."""

from __future__ import annotations

import re

import pytest
from fastapi.routing import APIRoute, iter_route_contexts

from backend.models.enums import Role

TABLES = ("submissions", "clicks", "masks", "jobs", "audit_events", "users")
TOO_BIG = 2**64  # SQLite's integers are 64-bit: this overflowed in the driver (a 500) before the bound


def _int_path_routes(app) -> list[tuple[str, str, list[str]]]:
    """(method, path, integer path parameters) of every API route, from the app itself: a route added later
    is covered without editing this test."""
    found = []
    for route in iter_route_contexts(app.routes):
        if not isinstance(route.original_route, APIRoute):
            continue
        names = [p.name for p in route.dependant.path_params if p.field_info.annotation is int]
        for method in sorted(route.methods - {"HEAD"}):
            if names:
                found.append((method, route.path, names))
    return found


def test_every_integer_path_id_is_bounded(sqlite_env, h):
    routes = _int_path_routes(sqlite_env.client.app)
    assert len(routes) >= 15  # the audit found 15; more is fine
    before = {t: h.count(sqlite_env, t) for t in TABLES}
    for method, path, names in routes:
        for name in names:
            url = re.sub(r"\{(\w+)\}", lambda m, name=name: str(TOO_BIG if m.group(1) == name else 1), path)
            body = {} if method in ("POST", "PATCH", "PUT") else None
            response = sqlite_env.client.request(method, url, json=body, headers=sqlite_env.headers(Role.admin))
            assert response.status_code == 422, (method, url, response.status_code, response.text)
            assert name in response.json()["detail"], (method, url, response.text)
    assert {t: h.count(sqlite_env, t) for t in TABLES} == before


@pytest.mark.parametrize("bad", ["0", "-3", str(TOO_BIG), "1e3", "abc"])
def test_a_path_id_outside_the_ids_is_422(sqlite_env, bad):
    response = sqlite_env.client.get(f"/api/admin/jobs/{bad}", headers=sqlite_env.headers(Role.admin))
    assert response.status_code == 422 and "job_id" in response.json()["detail"], response.text


@pytest.mark.parametrize(("field", "value"), [("keypoint", True), ("keypoint", "4"), ("keypoint", 4.5),
                                              ("x", "12"), ("x", True), ("view_id", "1"), ("visibility", 1),
                                              ("visibility", "seen")])
def test_loosely_typed_clicks_are_refused_and_nothing_is_written(env, h, field, value):
    ids = h.seed(env, frames=1, cameras=1)
    task = h.next_task(env)
    body = h.body(task)
    body["clicks"][0][field] = value
    before = {t: h.count(env, t) for t in TABLES}
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=body,
                               headers=env.headers(Role.annotator))
    assert response.status_code == 422, response.text
    assert f"clicks.0.{field}" in response.json()["detail"], response.text
    assert {t: h.count(env, t) for t in TABLES} == before


def test_proper_types_still_pass(sqlite_env, h):
    """Integers where floats are wanted and whole floats where integers are (JSON has one number type) are
    numbers, not coercion; enums take their values."""
    ids = h.seed(sqlite_env, frames=1, cameras=1)
    task = h.next_task(sqlite_env)
    body = h.body(task, time_spent_s=12)
    body["clicks"][0].update(x=10, y=20, visibility="occluded", keypoint=float(body["clicks"][0]["keypoint"]))
    response = sqlite_env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=body,
                                      headers=sqlite_env.headers(Role.annotator))
    assert response.status_code == 201, response.text


@pytest.mark.parametrize("body", [{"is_active": 1}, {"is_active": "false"}, {"role": "superuser"},
                                  {"full_name": 7}])
def test_loosely_typed_user_updates_are_refused(sqlite_env, body):
    user_id = sqlite_env.user_ids[Role.annotator]
    response = sqlite_env.client.patch(f"/api/admin/users/{user_id}", json=body, headers=sqlite_env.headers(Role.admin))
    assert response.status_code == 422, response.text
    assert next(iter(body)) in response.json()["detail"]
    me = sqlite_env.client.get("/api/auth/me", headers=sqlite_env.headers(Role.annotator))
    assert me.status_code == 200 and me.json()["is_active"] is True and me.json()["role"] == "annotator"


BAD_BODIES = {"not UTF-8": (b'{"lease_token": "\xff\xfe"}', "not UTF-8"),
              "nested deeply": (b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
              "malformed": (b'{"lease_token": ', "malformed JSON")}


@pytest.mark.parametrize("kind", sorted(BAD_BODIES))
def test_unreadable_bodies_are_401_without_a_token_and_422_naming_the_problem_with_one(sqlite_env, h, kind):
    """Authentication comes before the body is read: a caller without a valid token learns nothing else."""
    ids = h.seed(sqlite_env, frames=1, cameras=1)
    url = f"/api/annotate/samples/{ids[0]}/lease/renew"
    body, problem = BAD_BODIES[kind]
    json_type = {"content-type": "application/json"}
    anonymous = sqlite_env.client.post(url, content=body, headers=json_type)
    assert anonymous.status_code == 401 and anonymous.headers["www-authenticate"] == "Bearer", anonymous.text
    forged_token = {"Authorization": "Bearer 1.0.9999999999.x"}
    forged = sqlite_env.client.post(url, content=body, headers={**json_type, **forged_token})
    assert forged.status_code == 401, forged.text
    signed_in = sqlite_env.client.post(url, content=body, headers={**json_type, **sqlite_env.headers(Role.annotator)})
    assert signed_in.status_code == 422 and problem in signed_in.json()["detail"], signed_in.text


def test_an_unreadable_body_with_a_revoked_token_is_401(sqlite_env, h):
    headers = sqlite_env.headers(Role.annotator)
    user_id = sqlite_env.user_ids[Role.annotator]
    changed = sqlite_env.client.patch(f"/api/admin/users/{user_id}", json={"password": "another password 2"},
                                      headers=sqlite_env.headers(Role.admin))
    assert changed.status_code == 200
    response = sqlite_env.client.post("/api/annotate/prefetch", content=BAD_BODIES["not UTF-8"][0],
                                      headers={"content-type": "application/json", **headers})
    assert response.status_code == 401 and "revoked" in response.json()["detail"], response.text


@pytest.mark.parametrize(("method", "path", "body", "field"), [
    ("POST", "/api/admin/users", {"email": "a\u0000b@example.org", "password": "12345678"}, "email"),
    ("POST", "/api/admin/rounds", {"note": "a note\u0000"}, "note"),
    ("POST", "/api/admin/imports", {"path": "/tmp/a\u0000b"}, "path"),
    ("POST", "/api/annotate/samples/1/lease/renew", {"lease_token": "t\u0000"}, "lease_token")])
def test_text_with_a_nul_character_is_422_on_both_databases(env, h, method, path, body, field):
    """PostgreSQL cannot store NUL in text: it was a 500 there."""
    before = {t: h.count(env, t) for t in TABLES}
    response = env.client.request(method, path, json=body, headers=env.headers(Role.admin))
    assert response.status_code == 422 and field in response.json()["detail"] and "NUL" in response.json()["detail"]
    assert {t: h.count(env, t) for t in TABLES} == before


def test_nul_in_a_query_or_form_field_is_never_a_500(env):
    on_postgres = env.settings.resolved_database_url.startswith("postgresql")
    query = env.client.get("/api/admin/exports/samples?project=a%00b", headers=env.headers(Role.admin))
    login = env.client.post("/api/auth/token", data={"username": "a\u0000b@example.org", "password": "whatever1"})
    # The query parameter's schema refuses NUL (as PostgreSQL would), naming the parameter, on both databases.
    assert query.status_code == 422 and "project" in query.json()["detail"], query.text
    if on_postgres:  # the database refuses the form field's value: a 422 that says so
        assert login.status_code == 422 and "NUL" in login.json()["detail"], login.text
    else:  # SQLite stores any text: no such account
        assert login.status_code == 401, login.text


def test_the_published_email_pattern_and_the_server_agree_on_whitespace(sqlite_env):
    """A schema-driven client generates what the published pattern allows; each whitespace character (U+0085
    among them, which regex engines' `\\s` disagree on: fuzzing found it) is refused by both alike."""
    import re

    schema = sqlite_env.client.get("/openapi.json").json()["components"]["schemas"]["UserCreate"]
    pattern = schema["properties"]["email"]["pattern"]
    assert not re.search(r"\\[sSwWdD]", pattern), f"engine-dependent class shorthand in {pattern!r}"
    published = re.compile(pattern)
    for char in (c for c in map(chr, range(0x3001)) if c.isspace()):
        email = f"a{char}b@example.org"
        assert not published.search(email), repr(char)
        response = sqlite_env.client.post("/api/admin/users", json={"email": email, "password": "12345678"},
                                          headers=sqlite_env.headers(Role.admin))
        assert response.status_code == 422 and "email" in response.json()["detail"], (repr(char), response.text)
    assert published.search("\u00db@J\u023e.org")  # non-ASCII letters are fine
