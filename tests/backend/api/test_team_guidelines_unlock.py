"""Issue 38, item 11 (the admin's side): unlocking an account that failed logins locked, per-person statistics,
the labelling guidelines (read by everyone, edited by admins with a revision check) and the FreiHAND export
job's refusals. The limiter's clock is injected (no waiting)."""

from __future__ import annotations

import io
from datetime import timedelta

import pytest
from PIL import Image

from backend.db.base import utcnow
from backend.models.enums import Role
from backend.models.review import Decision
from backend.services.accounts.login_limits import LoginLimiter, LoginPolicy

PASSWORD = "correct horse battery"  # tests/backend/conftest.py


class FakeClock:
    now = 1000.0

    def __call__(self) -> float:
        return self.now


def _login(env, email: str, password: str):
    return env.client.post("/api/auth/token", data={"username": email, "password": password})


def test_an_admin_unlocks_an_account_that_failed_logins_locked(sqlite_env):
    env = sqlite_env
    policy = LoginPolicy(max_failures_per_account=3, max_failures_per_address=50, window_s=900.0,
                         max_concurrent_hashes=2, hash_wait_s=0.0)
    env.client.app.state.login_limiter = LoginLimiter(policy, clock=FakeClock())
    admin = env.headers(Role.admin)
    assert env.client.get("/api/admin/users/locks", headers=admin).json() == []
    for _ in range(3):
        assert _login(env, "ann@example.org", "wrong password").status_code == 401
    assert _login(env, "ann@example.org", PASSWORD).status_code == 429
    locks = env.client.get("/api/admin/users/locks", headers=admin).json()
    ann = env.user_ids[Role.annotator]
    assert locks == [{"user_id": ann, "email": "ann@example.org", "retry_after_s": 900}]
    assert env.client.post(f"/api/admin/users/{ann}/unlock", headers=env.headers(Role.reviewer)).status_code == 403
    assert env.client.post("/api/admin/users/999999/unlock", headers=admin).status_code == 404
    unlocked = env.client.post(f"/api/admin/users/{ann}/unlock", headers=admin)
    assert unlocked.status_code == 200, unlocked.text
    assert unlocked.json() == {"user_id": ann, "email": "ann@example.org", "was_locked": True}
    assert _login(env, "ann@example.org", PASSWORD).status_code == 200  # at once, not in 900 s
    assert env.client.get("/api/admin/users/locks", headers=admin).json() == []
    again = env.client.post(f"/api/admin/users/{ann}/unlock", headers=admin).json()
    assert again["was_locked"] is False


def _png(color=(200, 30, 30)) -> bytes:
    out = io.BytesIO()
    Image.new("RGB", (8, 6), color).save(out, "PNG")
    return out.getvalue()


def test_guidelines_are_read_by_everyone_and_edited_by_admins_without_overwriting(sqlite_env):
    env = sqlite_env
    admin, ann = env.headers(Role.admin), env.headers(Role.annotator)
    empty = env.client.get("/api/guidelines", headers=ann).json()
    assert (empty["text"], empty["images"], empty["revision"]) == ("", [], 0)
    assert env.client.put("/api/admin/guidelines", json={"text": "x", "revision": 0}, headers=ann).status_code == 403
    saved = env.client.put("/api/admin/guidelines", json={"text": "Occluded tips: O.", "revision": 0}, headers=admin)
    assert saved.status_code == 200, saved.text
    assert saved.json()["revision"] == 1
    stale = env.client.put("/api/admin/guidelines", json={"text": "older edit", "revision": 0}, headers=admin)
    assert stale.status_code == 409 and "someone else" in stale.json()["detail"], stale.text
    added = env.client.post("/api/admin/guidelines/images", headers=admin, data={"revision": "1", "caption": "a tip"},
                            files={"file": ("tip.png", _png(), "image/png")})
    assert added.status_code == 201, added.text
    [image] = added.json()["images"]
    assert image["caption"] == "a tip" and image["content_type"] == "image/png"
    served = env.client.get(f"/api/guidelines/images/{image['id']}", headers=ann)
    assert served.status_code == 200 and served.content == _png()
    not_image = env.client.post("/api/admin/guidelines/images", headers=admin, data={"revision": "2"},
                                files={"file": ("notes.txt", b"not an image", "text/plain")})
    assert not_image.status_code == 422 and "PNG, JPEG" in not_image.json()["detail"], not_image.text
    shown = env.client.get("/api/guidelines", headers=ann).json()
    assert (shown["text"], shown["revision"], len(shown["images"])) == ("Occluded tips: O.", 2, 1)
    gone = env.client.delete(f"/api/admin/guidelines/images/{image['id']}?revision=2", headers=admin)
    assert gone.status_code == 200 and gone.json()["images"] == []
    assert env.client.get(f"/api/guidelines/images/{image['id']}", headers=ann).status_code == 404
    assert env.client.get("/api/guidelines/images/not-an-id", headers=ann).status_code == 422


def test_per_person_statistics_count_what_they_say(sqlite_env, h):
    env = sqlite_env
    [first, second] = h.seed(env, frames=2, cameras=2)
    rev, adm = env.user_ids[Role.reviewer], env.user_ids[Role.admin]
    for _sample in (first, second):
        task = h.next_task(env)
        body = h.body(task, time_spent_s=30.0)
        # one view's wrist not annotated, one point taken from a proposal: counted apart
        body["clicks"][0].update(x=None, y=None, visibility="not_annotated")
        body["clicks"][1]["from_proposal"] = True
        response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body,
                                   headers=env.headers(Role.annotator))
        assert response.status_code == 201, response.text
    fit_a, fit_b = h.record_fit(env, first), h.record_fit(env, second)
    later = utcnow() + timedelta(minutes=1)
    with env.session() as session, session.begin():
        session.add_all([  # first: accepted by the reviewer, then rejected by the admin (overturned)
            Decision(sample_id=first, fit_id=fit_a, user_id=rev, decision="accept", created_at=later),
            Decision(sample_id=first, fit_id=fit_a, user_id=adm, decision="reject", reason="wrong finger",
                     created_at=later + timedelta(seconds=5)),
            # second: sent back for annotation by the reviewer
            Decision(sample_id=second, fit_id=fit_b, user_id=rev, decision="annotate", reason="tips",
                     created_at=later)])
    rows = {r["email"]: r for r in env.client.get("/api/admin/team/statistics", headers=env.headers(Role.admin)).json()}
    a, r = rows["ann@example.org"], rows["rev@example.org"]
    per_submission = len(body["clicks"])
    assert (a["samples"], a["submissions"]) == (2, 2)
    assert a["points_placed"] == 2 * (per_submission - 2) and a["proposals_accepted"] == 2
    assert a["seconds_per_sample"] == 30.0
    assert (a["decided"], a["accepted"], a["accept_rate"]) == (2, 1, 0.5)
    assert (r["decisions"], r["overturned"], r["samples"]) == (2, 1, 0)
    assert rows["admin@example.org"]["overturned"] == 0
    assert env.client.get("/api/admin/team/statistics", headers=env.headers(Role.reviewer)).status_code == 403


def test_the_freihand_export_job_is_refused_with_nothing_to_export(sqlite_env, h):
    env = sqlite_env
    admin = env.headers(Role.admin)
    refused = env.client.post("/api/admin/exports/freihand", json={}, headers=admin)
    assert refused.status_code == 409 and "no accepted sample" in refused.json()["detail"], refused.text
    assert env.client.post("/api/admin/exports/freihand", json={"meshes": "stl"}, headers=admin).status_code == 422
    as_reviewer = env.client.post("/api/admin/exports/freihand", json={}, headers=env.headers(Role.reviewer))
    assert as_reviewer.status_code == 403
    assert h.count(env, "jobs") == 0
    missing = env.client.get("/api/admin/exports/freihand/12345/archive", headers=admin)
    assert missing.status_code == 404, missing.text


@pytest.mark.parametrize("path", ["/api/admin/team/statistics", "/api/admin/users/locks"])
def test_admin_only_reads(sqlite_env, path):
    assert sqlite_env.client.get(path, headers=sqlite_env.headers(Role.annotator)).status_code == 403
