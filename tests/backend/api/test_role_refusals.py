"""Every route refuses anonymous callers and the roles ranked below its minimum."""

from __future__ import annotations

import pytest

from backend.models.enums import Role

# (method, path, minimum role)
ROUTES = [
    ("GET", "/api/auth/me", Role.annotator),
    ("POST", "/api/annotate/next", Role.annotator),
    ("POST", "/api/annotate/samples/1/lease/renew", Role.annotator),
    ("POST", "/api/annotate/samples/1/lease/release", Role.annotator),
    ("POST", "/api/annotate/samples/1/submissions", Role.annotator),
    ("POST", "/api/annotate/samples/1/skip", Role.annotator),
    ("GET", "/api/annotate/fit-failures", Role.annotator),
    ("GET", "/api/files/views/1/image", Role.annotator),
    ("GET", "/api/files/masks/1", Role.annotator),
    ("POST", "/api/review/next", Role.reviewer),
    ("POST", "/api/review/samples/1/lease/renew", Role.reviewer),
    ("POST", "/api/review/samples/1/lease/release", Role.reviewer),
    ("POST", "/api/review/samples/1/decision", Role.reviewer),
    ("GET", "/api/admin/users", Role.admin),
    ("POST", "/api/admin/users", Role.admin),
    ("PATCH", "/api/admin/users/1", Role.admin),
    ("GET", "/api/admin/rounds", Role.admin),
    ("POST", "/api/admin/rounds", Role.admin),
    ("POST", "/api/admin/rounds/1/cancel", Role.admin),
    ("GET", "/api/admin/rounds/statistics", Role.admin),
    ("POST", "/api/admin/rounds/review-queue", Role.admin),
    ("GET", "/api/admin/jobs", Role.admin),
    ("GET", "/api/admin/jobs/1", Role.admin),
    ("POST", "/api/admin/jobs/1/cancel", Role.admin),
    ("GET", "/api/admin/jobs/1/events", Role.admin),
    ("GET", "/api/admin/exports/dataset", Role.admin),
    ("GET", "/api/admin/exports/samples", Role.admin),
    ("GET", "/api/admin/exports/predictions", Role.admin),
    ("POST", "/api/admin/imports", Role.admin),
    ("GET", "/api/admin/preannotation", Role.admin),
    ("POST", "/api/admin/preannotation", Role.admin),
    ("GET", "/api/admin/reliability", Role.admin),
    ("POST", "/api/admin/samples/queue-for-annotation", Role.admin),
    # The browser UI's routes (tests/backend/api/ui/).
    ("POST", "/api/annotate/prefetch", Role.annotator),
    ("GET", "/api/annotate/samples/1/proposals", Role.annotator),
    ("POST", "/api/review/prefetch", Role.reviewer),
    ("GET", "/api/review/samples/1/overlay", Role.reviewer),
    ("POST", "/api/activity", Role.annotator),
    ("GET", "/api/admin/dashboard", Role.admin),
    ("GET", "/api/admin/projects/1/calibration-check", Role.admin),
    # Drafts and lapsed leases (tests/backend/api/test_drafts.py).
    ("POST", "/api/annotate/samples/1/lease/retake", Role.annotator),
    ("GET", "/api/annotate/samples/1/draft", Role.annotator),
    ("PUT", "/api/annotate/samples/1/draft", Role.annotator),
    ("DELETE", "/api/annotate/samples/1/draft", Role.annotator),
    ("POST", "/api/review/samples/1/lease/retake", Role.reviewer),
    ("GET", "/api/review/samples/1/draft", Role.reviewer),
    ("PUT", "/api/review/samples/1/draft", Role.reviewer),
    ("DELETE", "/api/review/samples/1/draft", Role.reviewer),
    # Issue 38: unlock, per-person statistics, the FreiHAND export job, the guidelines.
    ("GET", "/api/admin/users/locks", Role.admin),
    ("POST", "/api/admin/users/1/unlock", Role.admin),
    ("GET", "/api/admin/team/statistics", Role.admin),
    ("POST", "/api/admin/exports/freihand", Role.admin),
    ("GET", "/api/admin/exports/freihand/1/archive", Role.admin),
    ("GET", "/api/guidelines", Role.annotator),
    ("GET", "/api/guidelines/images/1", Role.annotator),
    ("PUT", "/api/admin/guidelines", Role.admin),
    ("POST", "/api/admin/guidelines/images", Role.admin),
    ("DELETE", "/api/admin/guidelines/images/1", Role.admin),
    # Issue 40: label quality (audit figures, settings, the audits with their labels).
    ("GET", "/api/admin/quality", Role.admin),
    ("PUT", "/api/admin/quality/settings", Role.admin),
    ("GET", "/api/admin/quality/audits", Role.admin),
    ("POST", "/api/admin/quality/gold", Role.admin),
]
# The 3D scene takes a scene ticket instead of a bearer token (tests/backend/api/ui/test_viewer_scene.py).
OPEN = {("GET", "/api/health"), ("POST", "/api/auth/token"), ("GET", "/api/viewer/samples/{x}/scene")}


def test_the_table_covers_every_route(sqlite_env):
    paths = sqlite_env.client.app.openapi()["paths"]
    declared = {(m.upper(), p) for p, ops in paths.items() for m in ops}
    listed = {(m, p.replace("/1", "/{x}")) for m, p, _ in ROUTES} | OPEN
    normalised = {(m, p.replace("{sample_id}", "{x}").replace("{view_id}", "{x}").replace("{mask_id}", "{x}")
                   .replace("{user_id}", "{x}").replace("{round_id}", "{x}").replace("{job_id}", "{x}")
                   .replace("{project_id}", "{x}").replace("{image_id}", "{x}"))
                  for m, p in declared}
    assert normalised == listed


REFUSALS = [(m, p, role) for m, p, minimum in ROUTES for role in Role if role.rank < minimum.rank]


@pytest.mark.parametrize(("method", "path", "role"), REFUSALS, ids=[f"{r.value}:{m} {p}" for m, p, r in REFUSALS])
def test_lower_roles_are_refused(sqlite_env, method, path, role):
    response = sqlite_env.client.request(method, path, headers=sqlite_env.headers(role), json={})
    assert response.status_code == 403, response.text
    assert "role" in response.json()["detail"]


@pytest.mark.parametrize(("method", "path"), [(m, p) for m, p, _ in ROUTES], ids=[f"{m} {p}" for m, p, _ in ROUTES])
def test_anonymous_is_refused(sqlite_env, method, path):
    response = sqlite_env.client.request(method, path, json={})
    assert response.status_code == 401
    assert response.headers["www-authenticate"] == "Bearer"


def test_bad_expired_and_revoked_tokens(sqlite_env):
    from backend.services.accounts.security import create_token

    env = sqlite_env
    for token, message in [("garbage", "malformed"), ("1.0.99999999999.bad", "invalid"),
                           (create_token(env.settings.secret_key, env.user_ids[Role.admin], 0, -10), "expired"),
                           (create_token(env.settings.secret_key, env.user_ids[Role.admin], 7, 100), "revoked")]:
        response = env.client.get("/api/auth/me", headers={"Authorization": f"Bearer {token}"})
        assert response.status_code == 401 and message in response.json()["detail"]
