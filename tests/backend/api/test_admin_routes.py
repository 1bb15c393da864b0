"""Admin: users, rounds, jobs (polling and SSE), statistics, exports; images and masks."""

from __future__ import annotations

import json

from sqlalchemy import text

from backend.db.base import utcnow
from backend.models.enums import JobState, Role
from backend.models.jobs import Job
from backend.services.jobs import jobs

ADMIN = Role.admin


def test_login_and_user_management(sqlite_env):
    env = sqlite_env
    bad = env.client.post("/api/auth/token", data={"username": "admin@example.org", "password": "wrong-password"})
    assert bad.status_code == 401 and "incorrect" in bad.json()["detail"]
    created = env.client.post("/api/admin/users", headers=env.headers(ADMIN),
                              json={"email": "New@Example.org", "password": "longenough", "role": "reviewer"})
    assert created.status_code == 201 and created.json()["email"] == "new@example.org"
    dup = env.client.post("/api/admin/users", headers=env.headers(ADMIN),
                          json={"email": "new@example.org", "password": "longenough"})
    assert dup.status_code == 409 and "already exists" in dup.json()["detail"]
    token = env.client.post("/api/auth/token", data={"username": "new@example.org", "password": "longenough"})
    assert token.status_code == 200
    auth = {"Authorization": f"Bearer {token.json()['access_token']}"}
    assert env.client.get("/api/auth/me", headers=auth).json()["role"] == "reviewer"
    uid = created.json()["id"]
    demoted = env.client.patch(f"/api/admin/users/{uid}", headers=env.headers(ADMIN), json={"is_active": False})
    assert demoted.status_code == 200 and demoted.json()["is_active"] is False
    assert env.client.get("/api/auth/me", headers=auth).status_code == 401  # old token revoked
    short = env.client.post("/api/admin/users", headers=env.headers(ADMIN), json={"email": "x@y.z", "password": "1"})
    assert short.status_code == 422 and "password" in short.json()["detail"]


def test_last_admin_cannot_be_demoted(sqlite_env):
    env = sqlite_env
    response = env.client.patch(f"/api/admin/users/{env.user_ids[ADMIN]}", headers=env.headers(ADMIN),
                                json={"role": "annotator"})
    assert response.status_code == 409 and "last active admin" in response.json()["detail"]


def _accept(env, h, n: int = 2) -> list[int]:
    """n samples accepted by the heuristic (confident predictions, a good fit): round 0's D^h."""
    ids = h.seed(env, frames=n, cameras=1, state="fitting")
    for sample_id in ids:
        h.record_fit(env, sample_id, prediction={"confidences": [0.95] * 21})
    return ids


def test_a_round_is_refused_below_the_minimum_of_accepted_labels_and_writes_nothing(env, h):
    _accept(env, h, 1)  # the test settings' minimum is 2
    before = {t: h.count(env, t) for t in ("rounds", "jobs", "audit_events")}
    refused = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={})
    assert refused.status_code == 409
    assert "1 accepted so far, at least 2 needed" in refused.json()["detail"]
    assert {t: h.count(env, t) for t in before} == before and env.queue.enqueued == []
    launch = env.client.get("/api/admin/dashboard", headers=env.headers(ADMIN)).json()["launch"]
    assert (launch["accepted"], launch["minimum"]) == (1, 2) and "Accept 1 more" in launch["refusal"]


def test_the_dashboard_counts_leased_samples_apart_from_free_ones(env, h):
    h.seed(env, frames=3, cameras=1)
    h.next_task(env)
    queues = env.client.get("/api/admin/dashboard", headers=env.headers(ADMIN)).json()["queues"]
    assert (queues["annotate"], queues["annotate_leased"]) == (2, 1)


def test_rounds_launch_cancel_and_jobs(env, h):
    _accept(env, h)
    launched = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={"mvnet_version": "mv-1"})
    assert launched.status_code == 201, launched.text
    body = launched.json()
    assert body["round"]["index"] == 1 and body["round"]["state"] == "running"
    assert env.queue.enqueued == [(body["job_id"], "round")]
    rounds = env.client.get("/api/admin/rounds", headers=env.headers(ADMIN)).json()
    assert [(r["index"], r["state"]) for r in rounds] == [(0, "completed"), (1, "running")]
    before = rounds[0]
    job = env.client.get(f"/api/admin/jobs/{body['job_id']}", headers=env.headers(ADMIN)).json()
    assert job["state"] == "queued" and job["kind"] == "round"
    cancelled = env.client.post(f"/api/admin/rounds/{body['round']['id']}/cancel", headers=env.headers(ADMIN))
    assert cancelled.status_code == 200 and cancelled.json()["state"] == "cancelled"
    assert cancelled.json()["failure"] is None
    assert env.queue.revoked == [body["job_id"]]
    # The round table as it was before the launch: D_0 open again with its labels, as after a failed round.
    rounds = env.client.get("/api/admin/rounds", headers=env.headers(ADMIN)).json()
    assert [(r["index"], r["state"]) for r in rounds] == [(0, "running"), (1, "cancelled")]
    assert rounds[0]["finished_at"] is None and before["finished_at"] is not None
    stats = env.client.get("/api/admin/rounds/statistics", headers=env.headers(ADMIN)).json()
    assert [r["index"] for r in stats["rounds"] if r["added_total"]] == [0]
    again = env.client.post(f"/api/admin/rounds/{body['round']['id']}/cancel", headers=env.headers(ADMIN))
    assert again.status_code == 409 and "only a running round" in again.json()["detail"]
    listed = env.client.get("/api/admin/jobs?state=cancelled", headers=env.headers(ADMIN)).json()
    assert [j["id"] for j in listed] == [body["job_id"]]


def test_job_progress_stream(sqlite_env, h):
    env = sqlite_env
    _accept(env, h)
    job_id = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={}).json()["job_id"]
    with env.session() as s, s.begin():
        jobs.update_progress(s, job_id, 0.5, "training")
        jobs.finish(s, job_id, JobState.succeeded)
    with env.client.stream("GET", f"/api/admin/jobs/{job_id}/events", headers=env.headers(ADMIN)) as response:
        assert response.headers["content-type"].startswith("text/event-stream")
        lines = [line for line in response.iter_lines() if line.startswith("data:")]
    final = json.loads(lines[-1][5:])
    assert final["state"] == "succeeded" and final["progress"] == 1.0
    missing = env.client.get("/api/admin/jobs/999/events", headers=env.headers(ADMIN))
    assert missing.status_code == 404 and "job 999 not found" in missing.json()["detail"]


def test_export_lists_accepted_samples(sqlite_env, h):
    env = sqlite_env
    ids = h.seed(env, frames=1, cameras=2, state="fitting")
    h.record_fit(env, ids[0], prediction={"confidences": [0.95] * 21})
    data = env.client.get("/api/admin/exports/dataset", headers=env.headers(ADMIN)).json()
    assert data["count"] == 1 and data["samples"][0]["stream"] == "heuristic"
    assert len(data["samples"][0]["fit"]["params"]) == 61


def test_images_and_masks_are_served_with_cache_headers(sqlite_env, h):
    env = sqlite_env
    ids = h.seed(env, frames=1, cameras=1)
    storage = env.client.app.state.storage
    with env.session() as s:
        view_id, key = s.execute(text("SELECT id, image_key FROM views")).one()
    storage.put_bytes(key, b"\x89PNG fake")
    url = f"/api/files/views/{view_id}/image"
    first = env.client.get(url, headers=env.headers(Role.annotator))
    assert first.status_code == 200 and first.content == b"\x89PNG fake"
    assert first.headers["content-type"] == "image/png" and "max-age=3600" in first.headers["cache-control"]
    cached = env.client.get(url, headers={**env.headers(Role.annotator), "If-None-Match": first.headers["etag"]})
    assert cached.status_code == 304
    assert env.client.get(url).status_code == 401
    # a corrected mask is stored as a PNG and served as the view's newest mask
    task = h.next_task(env)
    rle = [96 * 96 - 10, 10]
    body = h.body(task, masks=[{"view_id": view_id, "width": 96, "height": 96, "rle": rle}])
    assert env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=body,
                           headers=env.headers(Role.annotator)).status_code == 201
    with env.session() as s:
        mask_id, kind, version = s.execute(text("SELECT id, kind, version FROM masks")).one()
    assert (kind, version) == ("corrected", 1)
    png = env.client.get(f"/api/files/masks/{mask_id}", headers=env.headers(Role.annotator))
    assert png.status_code == 200 and png.content.startswith(b"\x89PNG")
    assert env.client.get("/api/files/masks/999", headers=env.headers(Role.annotator)).status_code == 404


def test_a_round_whose_training_fails_leaves_the_round_table_as_it_was(env, h):
    # The launch completes D_0 before anything trains; the training then fails (the worker asks for more
    # labels than the API did). D_0 must be open again as it was, D_1 marked failed, not left "running".
    from workers.tasks.context import build_context
    from workers.tasks.round_steps import start_round
    from workers.tasks.training import run_training_job

    first, second, late = h.seed(env, frames=3, cameras=1, state="fitting")
    for sample_id in (first, second):
        h.record_fit(env, sample_id, prediction={"confidences": [0.95] * 21})
    launched = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={"note": "first"}).json()
    h.record_fit(env, late, prediction={"confidences": [0.95] * 21})  # accepted while D_1 is open: joins it
    strict = env.settings.model_copy(update={"round_min_training_samples": 50})
    ctx = build_context(strict, job_queue=env.queue)
    try:
        train_ids = start_round(ctx, launched["job_id"])
        assert len(train_ids) == 2
        outcome = run_training_job(ctx, train_ids[0])
    finally:
        ctx.session_factory.kw["bind"].dispose()
    assert "at least 50" in outcome["failed"]
    rounds = env.client.get("/api/admin/rounds", headers=env.headers(ADMIN)).json()
    assert [(r["index"], r["state"]) for r in rounds] == [(0, "running"), (1, "failed")]
    assert rounds[0]["finished_at"] is None and rounds[0]["counts"] == {}  # as before the launch
    assert "at least 50" in rounds[1]["failure"] and rounds[0]["failure"] is None
    stats = env.client.get("/api/admin/rounds/statistics", headers=env.headers(ADMIN)).json()
    assert [(r["index"], r["added_total"]) for r in stats["rounds"]] == [(0, 3), (1, 0)]  # the late one joined D_0
    round_job = env.client.get(f"/api/admin/jobs/{launched['job_id']}", headers=env.headers(ADMIN)).json()
    assert round_job["state"] == "failed" and "at least 50" in round_job["error"]
    other = env.client.get(f"/api/admin/jobs/{train_ids[1]}", headers=env.headers(ADMIN)).json()
    assert other["state"] == "cancelled" and "round 1 failed" in other["error"]  # the other network stops
    # Launching again completes D_0 (now 3 labels) and opens the round after the failed one.
    again = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={})
    assert again.status_code == 201, again.text
    rounds = env.client.get("/api/admin/rounds", headers=env.headers(ADMIN)).json()
    assert [(r["index"], r["state"]) for r in rounds] == [(0, "completed"), (1, "failed"), (2, "running")]
    assert rounds[0]["counts"] == {"heuristic": 3}
    job = env.client.get(f"/api/admin/jobs/{again.json()['job_id']}", headers=env.headers(ADMIN)).json()
    assert job["state"] == "queued"


def test_a_round_job_reported_failed_twice_is_undone_once_and_its_round_stays_over(env, h):
    ids = h.seed(env, frames=2, cameras=1, state="fitting")
    for sample_id in ids:
        h.record_fit(env, sample_id, prediction={"confidences": [0.95] * 21})
    launched = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={}).json()
    with env.session() as session, session.begin():
        jobs.finish(session, launched["job_id"], JobState.failed, error="worker gave up")
        jobs.finish(session, launched["job_id"], JobState.failed, error="again")  # reported twice: once undone
    rounds = env.client.get("/api/admin/rounds", headers=env.headers(ADMIN)).json()
    assert [(r["index"], r["state"]) for r in rounds] == [(0, "running"), (1, "failed")]
    assert rounds[1]["failure"] == "worker gave up"
    cancelled = env.client.post(f"/api/admin/rounds/{rounds[1]['id']}/cancel", headers=env.headers(ADMIN))
    assert cancelled.status_code == 409  # a failed round is over


def test_the_round_progress_follows_its_phases_and_training_by_elapsed_budget(env, h):
    from workers.tasks import round_progress
    from workers.tasks.context import build_context
    from workers.tasks.round_steps import build_review_queue, run_heuristic, start_round

    ids = h.seed(env, frames=4, cameras=1, state="fitting")
    for sample_id in ids[:2]:
        h.record_fit(env, sample_id, prediction={"confidences": [0.95] * 21})
    h.set_state(env, ids[2:], "unlabeled")  # what the round will predict and fit
    launched = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={}).json()
    settings = env.settings.model_copy(update={"round_handsegnet_budget_s": 90.0, "round_mvnet_budget_s": 240.0})
    ctx = build_context(settings, job_queue=env.queue)
    try:
        train = dict(zip(("handsegnet", "mvnet"), start_round(ctx, launched["job_id"]), strict=True))
        total_s = 90 + 240 + 2 * (round_progress.PREDICT_S_PER_SAMPLE + round_progress.FIT_S_PER_SAMPLE) \
            + round_progress.FINISH_S

        def round_job() -> dict:
            return env.client.get(f"/api/admin/jobs/{launched['job_id']}", headers=env.headers(ADMIN)).json()

        assert round_job()["progress"] == 0.0 and "train HandSegNet" in round_job()["message"]
        with ctx.session_factory.begin() as session:  # HandSegNet 45 of its 90 s in
            jobs.update_progress(session, train["handsegnet"], 0.5, "training")
            round_progress.refresh(session, launched["job_id"], settings)
        job = round_job()
        assert abs(job["progress"] - 45 / total_s) < 1e-3, job
        assert job["message"] == "round 1: train HandSegNet (45 of 90 s), phase 1 of 5", job["message"]
        with ctx.session_factory.begin() as session:  # HandSegNet done, MVNet 120 of 240 s
            jobs.finish(session, train["handsegnet"], JobState.succeeded)
            jobs.update_progress(session, train["mvnet"], 0.5, "training")
            round_progress.refresh(session, launched["job_id"], settings)
        job = round_job()
        assert abs(job["progress"] - (90 + 120) / total_s) < 1e-3, job  # most of the bar: training is most
        assert "train MVNet (120 of 240 s), phase 2 of 5" in job["message"]
        assert [(p["name"], p["state"]) for p in job["result"]["phases"]] == [
            ("train HandSegNet", "done"), ("train MVNet", "running"), ("predict", "pending"), ("fit", "pending"),
            ("heuristic and review queue", "pending")]
        # The last steps merge their summaries into the result; the phases' refresh keeps them.
        with ctx.session_factory.begin() as session:
            jobs.finish(session, train["mvnet"], JobState.succeeded)
        assert run_heuristic(ctx, launched["job_id"]) is not None
        assert build_review_queue(ctx, launched["job_id"]) is not None
        job = round_job()
        assert {"heuristic", "review_queue", "candidates_estimate"} <= set(job["result"]), job["result"]
        assert job["result"]["phases"][-1]["state"] == "done"
        with ctx.session_factory.begin() as session:
            jobs.finish(session, launched["job_id"], JobState.succeeded)
    finally:
        ctx.session_factory.kw["bind"].dispose()
    assert round_job()["message"] == ""  # finished: no stale phase message


def test_a_step_capped_training_weighs_the_time_it_took_not_its_budget(env, h):
    """Issue 38 item 9: with the step-counted plan (7,200 s budgets, training stopped by a step cap after a few
    minutes) the bar read 100 % while prediction and fits were at 112 of 191. A train phase weighs its budget only
    until its own pace is known; once over, the time it took."""
    from datetime import timedelta

    from workers.tasks import round_progress
    from workers.tasks.context import build_context
    from workers.tasks.round_steps import start_round

    ids = h.seed(env, frames=4, cameras=1, state="fitting")
    for sample_id in ids[:2]:
        h.record_fit(env, sample_id, prediction={"confidences": [0.95] * 21})
    h.set_state(env, ids[2:], "unlabeled")
    launched = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={}).json()
    settings = env.settings.model_copy(update={"round_handsegnet_budget_s": 7200.0, "round_mvnet_budget_s": 7200.0})
    ctx = build_context(settings, job_queue=env.queue)
    try:
        train = dict(zip(("handsegnet", "mvnet"), start_round(ctx, launched["job_id"]), strict=True))
        t0 = utcnow() - timedelta(seconds=300)
        with ctx.session_factory.begin() as session:
            for net, (start, end) in {"handsegnet": (0, 130), "mvnet": (130, None)}.items():
                job = session.get(Job, train[net])
                job.started_at = t0 + timedelta(seconds=start)
                if end is not None:
                    jobs.finish(session, job.id, JobState.succeeded)
                    job.finished_at = t0 + timedelta(seconds=end)
            # MVNet 170 s in and half-way through its step cap: it will take ~340 s, not 7,200
            jobs.update_progress(session, train["mvnet"], 0.5, "training")
            round_job = session.get(Job, launched["job_id"])
            steps = round_progress.phases(session, round_job, settings, now=t0 + timedelta(seconds=300))
        weights = {p.name: p.weight_s for p in steps}
        assert weights["train HandSegNet"] == 130.0
        assert abs(weights["train MVNet"] - 340.0) < 1e-6
        # both networks done, nothing predicted yet: the bar is the training's share, not ~100 %
        with ctx.session_factory.begin() as session:
            jobs.finish(session, train["mvnet"], JobState.succeeded)
            session.get(Job, train["mvnet"]).finished_at = t0 + timedelta(seconds=470)
            progress = round_progress.refresh(session, launched["job_id"], settings)
        predict_fit = 2 * (round_progress.PREDICT_S_PER_SAMPLE + round_progress.FIT_S_PER_SAMPLE)
        expected = (130 + 340) / (130 + 340 + predict_fit + round_progress.FINISH_S)
        assert progress is not None and abs(progress - expected) < 1e-6, (progress, expected)
        # a train job not started yet weighs what the network's last training took, else its budget
        with ctx.session_factory() as session:
            assert round_progress._last_training_s(session, -1) == {"handsegnet": 130.0, "mvnet": 340.0}
            assert round_progress._last_training_s(session, round_job.round_id) == {}  # not this round's own
        queued = Job(kind="train", state=JobState.queued)
        assert round_progress.train_weight_s(queued, 7200.0, utcnow(), last_took_s=340.0) == 340.0
        assert round_progress.train_weight_s(queued, 90.0, utcnow()) == 90.0
    finally:
        ctx.session_factory.kw["bind"].dispose()


def test_one_round_at_a_time_and_a_cancelled_round_leaves_no_column(env, h):
    """Issue 38 item 5: launching while the open round's job still trains completed that round with no models
    and queued another; now 409 naming the running job, nothing written, and the dashboard's launch says why
    (the page disables the button). A cancelled round leaves no row or column in the statistics."""
    ids = h.seed(env, frames=2, cameras=1, state="fitting")
    for sample_id in ids:
        h.record_fit(env, sample_id, prediction={"confidences": [0.95] * 21})
    launched = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={"note": "first"})
    assert launched.status_code == 201, launched.text
    job_id = launched.json()["job_id"]
    before = env.client.get("/api/admin/rounds", headers=env.headers(ADMIN)).json()
    again = env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={"note": "second"})
    assert again.status_code == 409, again.text
    assert "one round at a time" in again.json()["detail"] and f"job {job_id} is queued" in again.json()["detail"]
    assert env.client.get("/api/admin/rounds", headers=env.headers(ADMIN)).json() == before  # nothing written
    launch = env.client.get("/api/admin/dashboard", headers=env.headers(ADMIN)).json()["launch"]
    assert launch["refusal"] and "one round at a time" in launch["refusal"]
    cancelled = env.client.post(f"/api/admin/rounds/{launched.json()['round']['id']}/cancel",
                                headers=env.headers(ADMIN))
    assert cancelled.status_code == 200, cancelled.text
    stats = env.client.get("/api/admin/rounds/statistics", headers=env.headers(ADMIN)).json()
    assert [(r["index"], r["state"]) for r in stats["rounds"]] == [(0, "running")]  # no "D1 cancelled" column
    assert env.client.get("/api/admin/dashboard", headers=env.headers(ADMIN)).json()["launch"]["refusal"] is None
    assert env.client.post("/api/admin/rounds", headers=env.headers(ADMIN), json={}).status_code == 201


def test_the_statistics_count_points_placed_by_hand(env, h):
    """'clicks' counts the points a person placed: not the not-annotated rows a submission carries for every other
    keypoint, nor proposals accepted as they were (issue 38: the page said '336 clicks' for submissions x 48)."""
    h.seed(env, frames=2, cameras=2)
    task = h.next_task(env)
    view, other = task["views"][0]["id"], task["views"][1]["id"]
    clicks = [{"view_id": view, "keypoint": 0, "x": 10.0, "y": 20.0, "visibility": "visible"},
              {"view_id": view, "keypoint": 4, "x": 30.0, "y": 20.0, "visibility": "occluded"},
              {"view_id": other, "keypoint": 0, "x": 11.0, "y": 21.0, "visibility": "visible", "from_proposal": True},
              {"view_id": other, "keypoint": 4, "x": None, "y": None, "visibility": "not_annotated"}]
    response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions",
                               json=h.body(task, clicks=clicks), headers=env.headers(Role.annotator))
    assert response.status_code in (200, 201), response.text
    stats = env.client.get("/api/admin/rounds/statistics", headers=env.headers(ADMIN)).json()
    assert (stats["submissions"], stats["clicks"]) == (1, 2), stats
