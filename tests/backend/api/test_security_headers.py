"""Security headers on every response and the API docs served from this server (issue #13, defect 10). That the
pages still work under these policies is checked in Chromium (tests/browser/test_security_headers.py)."""

from __future__ import annotations

import re

import pytest

from backend.api.security_headers import viewer_policy
from backend.models.enums import Role


def _directives(policy: str) -> dict[str, list[str]]:
    return {d.split()[0]: d.split()[1:] for d in (p.strip() for p in policy.split(";")) if d}


@pytest.mark.parametrize(("path", "frame_ancestors"), [("/", "'none'"), ("/js/main.js", "'none'"),
                                                       ("/docs", "'none'"), ("/viewer/", "'self'"),
                                                       ("/api/health", "'none'"), ("/api/admin/users", "'none'"),
                                                       ("/no-such-page", "'none'")])
def test_every_response_carries_the_headers(sqlite_env, path, frame_ancestors):
    response = sqlite_env.client.get(path)
    assert response.headers["x-content-type-options"] == "nosniff"
    assert response.headers["referrer-policy"] == "no-referrer"
    policy = _directives(response.headers["content-security-policy"])
    assert policy["frame-ancestors"] == [frame_ancestors]
    assert policy["object-src"] == ["'none'"] and "'unsafe-inline'" not in policy["script-src"]
    assert ("'unsafe-eval'" in policy["script-src"]) == path.startswith("/viewer")  # viser's embind needs it


def test_errors_from_the_middleware_carry_them_too(env_with, sqlite_url, tmp_path):
    env = env_with(sqlite_url, tmp_path, max_upload_bytes=2048)
    response = env.client.post("/api/activity", content=b"x" * 4096, headers={"content-type": "application/json",
                                                                                 **env.headers(Role.annotator)})
    assert response.status_code == 413 and response.headers["x-content-type-options"] == "nosniff"
    assert "frame-ancestors 'none'" in response.headers["content-security-policy"]


def test_the_viewer_allows_exactly_viser_s_two_scripts():
    script_src = _directives(viewer_policy())["script-src"]
    assert sum(s.startswith("'sha256-") for s in script_src) == 2 and "'wasm-unsafe-eval'" in script_src
    assert "'unsafe-inline'" not in script_src  # any other inline script is refused


def test_docs_reference_no_other_host_and_their_files_are_served(sqlite_env):
    client = sqlite_env.client
    page = client.get("/docs")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    references = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert len(references) >= 4
    for ref in references:
        assert ref.startswith("/") and not ref.startswith("//"), ref  # this server, no CDN
        served = client.get(ref)
        assert served.status_code == 200 and len(served.content) > 0, ref
    assert "<script>" not in page.text  # no inline script: the CSP allows none
    init = client.get("/docs/init.js").text
    assert "validatorUrl: null" in init and "http" not in init
    assert client.get("/redoc").status_code == 404  # FastAPI's ReDoc page loads from a CDN: not served
