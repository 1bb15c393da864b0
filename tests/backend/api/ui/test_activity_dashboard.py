"""Activity logs (time per action) and the admin dashboard that averages them."""

from __future__ import annotations

import uuid

from backend.models.enums import Role


def _actions(view_id: int) -> list[dict]:
    # Six keypoints at 1.5 s each (one accepted proposal), then one mask corrected in 3 strokes (9 s).
    out = [{"kind": "click" if k else "accept", "at_ms": 1500.0 * (k + 1), "duration_ms": 1500.0, "view_id": view_id,
            "keypoint": kp} for k, kp in enumerate((0, 4, 8, 12, 16, 20))]
    out += [{"kind": "brush", "at_ms": 9000.0 + 3000 * i, "duration_ms": 3000.0, "view_id": view_id} for i in range(3)]
    return out


def _submitted(env, h):
    h.seed(env, frames=2, cameras=2)
    task = h.next_task(env)
    body = h.body(task)
    response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body,
                               headers=env.headers(Role.annotator))
    assert response.status_code == 201
    return task, body["submission_id"]


def test_annotation_log_is_stored_once_and_summarised(env, h):
    task, submission_id = _submitted(env, h)
    log = {"context": "annotate", "sample_id": task["sample_id"], "submission_id": submission_id,
           "time_spent_s": 20.0, "actions": _actions(task["views"][0]["id"])}
    first = env.client.post("/api/activity", json=log, headers=env.headers(Role.annotator))
    assert first.status_code == 201, first.text
    assert first.json()["summary"] == {"time_spent_s": 20.0, "keypoints_set": 6, "keypoint_s": 9.0,
                                       "masks_corrected": 1, "mask_s": 9.0, "actions": 9}
    again = env.client.post("/api/activity", json=log, headers=env.headers(Role.annotator))
    assert again.status_code == 200 and again.json()["duplicate"] is True and again.json()["id"] == first.json()["id"]
    assert h.count(env, "audit_events WHERE action = 'ui.activity'") == 1
    human = env.client.get("/api/admin/dashboard", headers=env.headers(Role.admin)).json()["human_time"]
    assert human["seconds_per_keypoint"] == 1.5 and human["seconds_per_mask"] == 9.0
    assert human["paper_seconds"] == {"keypoint": 2.0, "mask": 12.0, "verification": 5.0}


def test_logs_of_others_or_of_nothing_are_refused(env, h):
    task, submission_id = _submitted(env, h)
    log = {"context": "annotate", "sample_id": task["sample_id"], "submission_id": submission_id,
           "time_spent_s": 5.0, "actions": []}
    response = env.client.post("/api/activity", json=log, headers=env.headers(Role.reviewer))
    assert response.status_code == 403 and "not yours" in response.json()["detail"]
    response = env.client.post("/api/activity", json={**log, "submission_id": uuid.uuid4().hex},
                               headers=env.headers(Role.annotator))
    assert response.status_code == 404
    response = env.client.post("/api/activity", json={**log, "sample_id": task["sample_id"] + 1},
                               headers=env.headers(Role.annotator))
    assert response.status_code == 422 and "belongs to sample" in response.json()["detail"]
    response = env.client.post("/api/activity", json={**log, "submission_id": None},
                               headers=env.headers(Role.annotator))
    assert response.status_code == 422 and "needs the submission_id" in response.json()["detail"]
    bad = {**log, "actions": [{"kind": "click", "at_ms": float("nan"), "duration_ms": 1.0}]}
    response = env.client.post("/api/activity", content=__import__("json").dumps(bad).replace("NaN", "1e999"),
                               headers={**env.headers(Role.annotator), "content-type": "application/json"})
    assert response.status_code == 422
    response = env.client.post("/api/activity", json={**log, "actions": [{"kind": "dance", "at_ms": 0,
                                                                          "duration_ms": 0}]},
                               headers=env.headers(Role.annotator))
    assert response.status_code == 422 and "kind" in response.json()["detail"]
    assert h.count(env, "audit_events WHERE action = 'ui.activity'") == 0


def test_review_log_and_dashboard_figures(env, h):
    ids = h.seed(env, frames=3, cameras=2, state="fitting")
    for sid, conf in zip(ids, (0.95, 0.62, 0.3), strict=True):
        h.record_fit(env, sid, prediction={"confidences": [conf] * 21}, offset_m=0.001 if conf > 0.9 else 0.004)
    h.set_state(env, ids[1:], "in_review")
    task = h.next_task(env, Role.reviewer, "review")
    decision = env.client.post(f"/api/review/samples/{task['sample_id']}/decision", json={"decision": "accept"},
                               headers=env.headers(Role.reviewer)).json()
    log = {"context": "review", "sample_id": task["sample_id"], "decision_id": decision["id"], "time_spent_s": 2.5,
           "actions": [{"kind": "decide", "at_ms": 2500.0, "duration_ms": 2500.0}]}
    assert env.client.post("/api/activity", json=log, headers=env.headers(Role.reviewer)).status_code == 201
    data = env.client.get("/api/admin/dashboard", headers=env.headers(Role.admin)).json()
    assert data["human_time"]["seconds_per_verification"] == 2.5
    hist = data["confidence_histogram"]
    assert hist["n"] == 3 and sum(hist["counts"]) == 3 and sum(hist["accepted"]) == 2  # heuristic + manual
    sp = data["sparsification"]
    assert sp["n"] == 2 and sp["curve_mm"][0] > 0 and len(sp["fractions"]) == 20
    assert data["queues"] == {"annotate": 0, "review": 1, "annotate_leased": 0, "review_leased": 0}
    assert data["fits"] == 3
    assert data["fits_by_hand_model"] == {"built-in stand-in hand, not MANO": 3}  # conftest fits say "builtin"


def test_logs_as_the_pages_send_them_are_accepted_and_counted(env, h):
    """Issue 38 item 6: the review page marks a picked reason ("reason") and the annotate page a drag that moved
    accepted proposals with it ("reprojected"); both logs were refused (422) and the dashboard undercounted."""
    ids = h.seed(env, frames=3, cameras=2, state="fitting")
    for sid in ids:
        h.record_fit(env, sid, prediction={"confidences": [0.5] * 21}, offset_m=0.004)  # not auto-accepted
    h.set_state(env, ids, "in_review")
    for n, decision in enumerate(("accept", "reject", "annotate")):
        task = h.next_task(env, Role.reviewer, "review")
        body = {"decision": decision, "reason": "" if decision == "accept" else "wrong finger order"}
        made = env.client.post(f"/api/review/samples/{task['sample_id']}/decision", json=body,
                               headers=env.headers(Role.reviewer))
        assert made.status_code in (200, 201), (n, made.text)
        actions = [{"kind": "reason", "at_ms": 1000.0, "duration_ms": 1000.0}] if decision != "accept" else []
        actions.append({"kind": "decide", "at_ms": 2000.0, "duration_ms": 1000.0})
        log = {"context": "review", "sample_id": task["sample_id"], "decision_id": made.json()["id"],
               "time_spent_s": 2.0, "actions": actions}
        response = env.client.post("/api/activity", json=log, headers=env.headers(Role.reviewer))
        assert response.status_code == 201, (n, response.text)
    human = env.client.get("/api/admin/dashboard", headers=env.headers(Role.admin)).json()["human_time"]
    assert human["verifications"] == 3


def test_drag_that_moved_accepted_proposals_is_accepted(env, h):
    task, submission_id = _submitted(env, h)
    view_id = task["views"][0]["id"]
    log = {"context": "annotate", "sample_id": task["sample_id"], "submission_id": submission_id,
           "time_spent_s": 3.0, "actions": [{"kind": "drag", "at_ms": 3000.0, "duration_ms": 3000.0,
                                             "view_id": view_id, "keypoint": 4, "reprojected": 1}]}
    response = env.client.post("/api/activity", json=log, headers=env.headers(Role.annotator))
    assert response.status_code == 201, response.text
    assert response.json()["summary"]["keypoints_set"] == 1
    stored = h.count(env, "audit_events WHERE action = 'ui.activity'")
    assert stored == 1
    bad = {**log, "submission_id": uuid.uuid4().hex, "actions": [{**log["actions"][0], "reprojected": -1}]}
    response = env.client.post("/api/activity", json=bad, headers=env.headers(Role.annotator))
    assert response.status_code == 422 and "reprojected" in response.json()["detail"]
