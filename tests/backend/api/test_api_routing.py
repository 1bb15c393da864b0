"""Issue 38 item 12: a request on an /api path is answered by the API, never by the UI's static files: a wrong
method gets 405 with the allowed ones in `Allow`, an unknown path a JSON 404, both saying what to do."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize(("method", "path", "allowed"), [
    ("OPTIONS", "/api/annotate/next", "POST"), ("GET", "/api/annotate/next", "POST"),
    ("DELETE", "/api/health", "GET"), ("PUT", "/api/auth/token", "POST")])
def test_a_wrong_method_on_an_api_path_is_the_apis_405(sqlite_env, method, path, allowed):
    response = sqlite_env.client.request(method, path)
    assert response.status_code == 405, response.text
    assert response.headers["allow"] == allowed
    assert response.headers["content-type"] == "application/json"
    assert f"{method} is not allowed on {path}; use {allowed}" in response.json()["detail"]


@pytest.mark.parametrize("path", ["/api/no-such-thing", "/api", "/api/annotate/samples/1/nothing"])
def test_an_unknown_api_path_is_a_json_404(sqlite_env, path):
    response = sqlite_env.client.get(path)
    assert response.status_code == 404 and response.headers["content-type"] == "application/json"
    assert "no such API path" in response.json()["detail"]


def test_the_ui_is_still_served_outside_api(sqlite_env):
    assert sqlite_env.client.get("/").status_code == 200
    assert sqlite_env.client.get("/js/api.js").status_code == 200
    missing = sqlite_env.client.get("/js/nothing.js")
    assert missing.status_code == 404 and "no such API path" not in missing.text
