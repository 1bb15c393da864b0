"""Annotator queue: leases, idempotent submissions, bad input, one transaction per request."""

from __future__ import annotations

from datetime import timedelta

import pytest
from sqlalchemy import text

from backend.db.base import utcnow
from backend.models.enums import Role

TABLES = ("submissions", "clicks", "masks", "jobs", "audit_events")


def test_next_submit_queues_a_fit(env, h):
    ids = h.seed(env, frames=3, cameras=2)
    task = h.next_task(env)
    assert task["sample_id"] == ids[0]
    assert task["keypoints_to_click"] == [0, 4, 8, 12, 16, 20]
    assert len(task["views"]) == 2 and task["views"][0]["image_url"].startswith("/api/files/views/")
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task),
                               headers=env.headers(Role.annotator))
    assert response.status_code == 201, response.text
    data = response.json()
    assert data["n_clicks"] == 12 and data["duplicate"] is False
    assert env.queue.enqueued == [(data["fit_job_id"], "fit")]  # handed over after commit
    with env.session() as s:
        assert s.execute(text("SELECT state, leased_by_id FROM samples WHERE id = :i"), {"i": ids[0]}).one() == (
            "fitting", None)
    assert h.count(env, "clicks") == 12


def test_next_returns_the_same_lease_until_submitted(env, h):
    h.seed(env, frames=3, cameras=1)
    first, again = h.next_task(env), h.next_task(env)
    assert first["sample_id"] == again["sample_id"] and first["lease_token"] == again["lease_token"]


def test_empty_queue_gives_204(env, h):
    h.seed(env, frames=1, cameras=1, state="unlabeled")
    assert env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).status_code == 204


def test_resubmission_is_idempotent(env, h):
    ids = h.seed(env, frames=2, cameras=2)
    task = h.next_task(env)
    body = h.body(task, client_id="client-abc-123")
    url = f"/api/annotate/samples/{ids[0]}/submissions"
    first = env.client.post(url, json=body, headers=env.headers(Role.annotator))
    counts = {t: h.count(env, t) for t in TABLES}
    second = env.client.post(url, json=body, headers=env.headers(Role.annotator))
    assert (first.status_code, second.status_code) == (201, 200)
    assert second.json()["duplicate"] is True and second.json()["id"] == first.json()["id"]
    assert {t: h.count(env, t) for t in TABLES} == counts
    assert len(env.queue.enqueued) == 1


def test_submission_id_reused_for_another_sample_is_refused(env, h):
    ids = h.seed(env, frames=2, cameras=1)
    task = h.next_task(env)
    body = h.body(task, client_id="client-abc-123")
    assert env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=body,
                           headers=env.headers(Role.annotator)).status_code == 201
    task2 = h.next_task(env)
    response = env.client.post(f"/api/annotate/samples/{task2['sample_id']}/submissions",
                               json=h.body(task2, client_id="client-abc-123"), headers=env.headers(Role.annotator))
    assert response.status_code == 409 and "already used" in response.json()["detail"]


def test_lease_expiry_returns_the_sample(env, h):
    ids = h.seed(env, frames=1, cameras=1)
    task = h.next_task(env, Role.annotator)
    # a second annotator (the reviewer may annotate too) finds the queue empty while the lease lives
    assert env.client.post("/api/annotate/next", headers=env.headers(Role.reviewer)).status_code == 204
    with env.session() as s, s.begin():
        s.execute(text("UPDATE samples SET lease_expires_at = :t"), {"t": utcnow() - timedelta(seconds=1)})
    other = h.next_task(env, Role.reviewer)
    assert other["sample_id"] == ids[0]
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task),
                               headers=env.headers(Role.annotator))
    assert response.status_code == 403 and "no annotate lease" in response.json()["detail"]


def test_submit_after_own_lease_expired_is_409(env, h):
    ids = h.seed(env, frames=1, cameras=1)
    task = h.next_task(env)
    with env.session() as s, s.begin():
        s.execute(text("UPDATE samples SET lease_expires_at = :t"), {"t": utcnow() - timedelta(seconds=1)})
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task),
                               headers=env.headers(Role.annotator))
    assert response.status_code == 409 and "expired" in response.json()["detail"]
    assert h.count(env, "submissions") == 0


def test_renew_and_release(env, h):
    ids = h.seed(env, frames=1, cameras=1)
    task = h.next_task(env)
    url = f"/api/annotate/samples/{ids[0]}"
    renewed = env.client.post(f"{url}/lease/renew", json={"lease_token": task["lease_token"]},
                              headers=env.headers(Role.annotator))
    assert renewed.status_code == 200 and renewed.json()["lease_expires_at"] >= task["lease_expires_at"]
    wrong = env.client.post(f"{url}/lease/renew", json={"lease_token": "nope"}, headers=env.headers(Role.annotator))
    assert wrong.status_code == 403 and "token" in wrong.json()["detail"]
    assert env.client.post(f"{url}/lease/release", json={}, headers=env.headers(Role.annotator)).status_code == 204
    assert h.next_task(env, Role.reviewer)["sample_id"] == ids[0]


def _bad_cases():
    def view0(t):
        return t["views"][0]["id"]

    return [
        ("x outside the image", lambda t: {"clicks": [{"view_id": view0(t), "keypoint": 0, "x": 96.0, "y": 5.0}]},
         422, "outside view"),
        ("negative y", lambda t: {"clicks": [{"view_id": view0(t), "keypoint": 0, "x": 5.0, "y": -0.6}]},
         422, "outside view"),
        ("unknown view", lambda t: {"clicks": [{"view_id": 999999, "keypoint": 0, "x": 1.0, "y": 1.0}]},
         422, "is not a view of sample"),
        ("unknown keypoint", lambda t: {"clicks": [{"view_id": view0(t), "keypoint": 21, "x": 1.0, "y": 1.0}]},
         422, "clicks.0.keypoint"),
        ("keypoint given twice", lambda t: {"clicks": [{"view_id": view0(t), "keypoint": 0, "x": 1.0, "y": 1.0},
                                                       {"view_id": view0(t), "keypoint": 0, "x": 2.0, "y": 1.0}]},
         422, "given twice"),
        ("visible without x", lambda t: {"clicks": [{"view_id": view0(t), "keypoint": 0, "y": 1.0}]},
         422, "needs both x and y"),
        ("mask of the wrong size", lambda t: {"clicks": [], "masks": [
            {"view_id": view0(t), "width": 10, "height": 10, "rle": [100]}]}, 422, "is 96x96"),
        ("rle not covering the mask", lambda t: {"clicks": [], "masks": [
            {"view_id": view0(t), "width": 96, "height": 96, "rle": [5, 5]}]}, 422, "covers 10 pixels"),
        ("empty submission", lambda t: {"clicks": []}, 422, "needs clicks or masks"),
        ("unknown field", lambda t: {"colour": "red"}, 422, "colour"),
        ("negative time", lambda t: {"time_spent_s": -1}, 422, "time_spent_s"),
    ]


@pytest.mark.parametrize(("case", "patch", "status", "message"), _bad_cases(), ids=[c[0] for c in _bad_cases()])
def test_bad_submission_is_refused_and_writes_nothing(env, h, case, patch, status, message):
    ids = h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    before = {t: h.count(env, t) for t in TABLES}
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task, **patch(task)),
                               headers=env.headers(Role.annotator))
    assert response.status_code == status, response.text
    assert message in response.json()["detail"]
    assert {t: h.count(env, t) for t in TABLES} == before
    with env.session() as s:
        assert s.execute(text("SELECT state FROM samples")).scalar_one() == "needs_annotation"


@pytest.mark.parametrize("raw", ['{"x": 1.0e999}', "NaN", "{not json", '{"submission_id": "abcdefgh",'])
def test_malformed_or_non_finite_json_is_422(sqlite_env, h, raw):
    env = sqlite_env
    ids = h.seed(env, frames=1, cameras=1)
    h.next_task(env)
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", content=raw,
                               headers={**env.headers(Role.annotator), "Content-Type": "application/json"})
    assert response.status_code == 422
    assert response.json()["detail"]


def test_non_finite_click_is_refused(sqlite_env, h):
    env = sqlite_env
    ids = h.seed(env, frames=1, cameras=1)
    task = h.next_task(env)
    body = h.body(task)
    raw = __import__("json").dumps(body).replace('"x": 10.0', '"x": Infinity', 1)
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", content=raw,
                               headers={**env.headers(Role.annotator), "Content-Type": "application/json"})
    assert response.status_code == 422
    assert h.count(env, "clicks") == 0


def test_oversized_upload_is_413(sqlite_url, tmp_path, h, env_with):
    env = env_with(sqlite_url, tmp_path, max_upload_bytes=4096)
    ids = h.seed(env, frames=1, cameras=8)
    task = h.next_task(env)
    body = h.body(task, time_spent_s=1.0)
    body["clicks"] = body["clicks"] * 3  # 144 clicks: well over 4 KiB of JSON
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=body,
                               headers=env.headers(Role.annotator))
    assert response.status_code == 413 and "exceeds the limit of 4096 bytes" in response.json()["detail"]

    def chunks():
        data = __import__("json").dumps(body).encode()
        for i in range(0, len(data), 1000):
            yield data[i:i + 1000]

    streamed = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", content=chunks(),
                               headers={**env.headers(Role.annotator), "Content-Type": "application/json"})
    assert streamed.status_code == 413
    assert h.count(env, "submissions") == 0


def test_too_many_clicks_is_422(sqlite_url, tmp_path, h, env_with):
    env = env_with(sqlite_url, tmp_path, max_clicks_per_submission=5)
    ids = h.seed(env, frames=1, cameras=1)
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(h.next_task(env)),
                               headers=env.headers(Role.annotator))
    assert response.status_code == 422 and "at most 5" in response.json()["detail"]


def test_a_task_names_its_sequence_as_the_exports_do(env, h):
    h.seed(env, frames=1, cameras=1)
    task = h.next_task(env)
    assert task["sequence"] == "seq000" and isinstance(task["sequence_id"], int)


def test_keypoints_accepted_from_proposals_are_stored_as_such(env, h):
    ids = h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    body = h.body(task)
    for click in body["clicks"][:3]:
        click["from_proposal"] = True
    response = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=body,
                               headers=env.headers(Role.annotator))
    assert response.status_code == 201, response.text
    with env.session() as s:
        flags = s.execute(text("SELECT from_proposal, count(*) FROM clicks GROUP BY from_proposal")).all()
    assert {bool(f): n for f, n in flags} == {True: 3, False: 9}
    bad = h.body(task)
    bad["clicks"][0]["from_proposal"] = "maybe"
    assert env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=bad,
                           headers=env.headers(Role.annotator)).status_code == 422
