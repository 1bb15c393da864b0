"""Reviewer queue, decisions and the heuristic path through the server."""

from __future__ import annotations

from sqlalchemy import text

from backend.models.enums import Role

GOOD = {"confidences": [0.9] * 21}


def _annotated_and_fitted(env, h, frames=1, cameras=2):
    ids = h.seed(env, frames=frames, cameras=cameras)
    for _ in ids:
        task = h.next_task(env)
        response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=h.body(task),
                                   headers=env.headers(Role.annotator))
        assert response.status_code == 201
        h.record_fit(env, task["sample_id"], from_clicks=True)
    return ids


def test_fit_from_clicks_goes_to_review_and_accept_joins_round_as_annotated(env, h):
    ids = _annotated_and_fitted(env, h)
    task = h.next_task(env, Role.reviewer, "review")
    assert task["sample_id"] == ids[0] and task["fit"]["model_file"] == "builtin"
    response = env.client.post(f"/api/review/samples/{ids[0]}/decision", json={"decision": "accept"},
                               headers=env.headers(Role.reviewer))
    assert response.status_code == 201, response.text
    assert response.json()["state"] == "accepted" and response.json()["stream"] == "annotated"
    stats = env.client.get("/api/admin/rounds/statistics", headers=env.headers(Role.admin)).json()
    assert stats["rounds"][0]["added"]["annotated"] == 1 and stats["rounds"][0]["dataset_size_after"] == 1


def test_annotate_decision_sends_back_to_annotators(env, h):
    ids = _annotated_and_fitted(env, h)
    h.next_task(env, Role.reviewer, "review")
    response = env.client.post(f"/api/review/samples/{ids[0]}/decision",
                               json={"decision": "annotate", "reason": "index tip on the wrong finger"},
                               headers=env.headers(Role.reviewer))
    assert response.status_code == 201 and response.json()["state"] == "needs_annotation"
    assert h.next_task(env)["sample_id"] == ids[0]


def test_reject_needs_a_reason(env, h):
    ids = _annotated_and_fitted(env, h)
    h.next_task(env, Role.reviewer, "review")
    response = env.client.post(f"/api/review/samples/{ids[0]}/decision", json={"decision": "reject"},
                               headers=env.headers(Role.reviewer))
    assert response.status_code == 422 and "needs a reason" in response.json()["detail"]


def test_decision_without_lease_or_in_wrong_state_is_refused(env, h):
    ids = h.seed(env, frames=2, cameras=1)
    # needs_annotation: not in review at all
    response = env.client.post(f"/api/review/samples/{ids[0]}/decision", json={"decision": "accept"},
                               headers=env.headers(Role.reviewer))
    assert response.status_code == 409 and "not in the review queue" in response.json()["detail"]
    assert h.count(env, "decisions") == 0


def test_reviewer_cannot_accept_without_a_fit(env, h):
    ids = h.seed(env, frames=1, cameras=1, state="in_review")  # forced into review with no fit
    h.next_task(env, Role.reviewer, "review")
    response = env.client.post(f"/api/review/samples/{ids[0]}/decision", json={"decision": "accept"},
                               headers=env.headers(Role.reviewer))
    assert response.status_code == 409 and "no fit" in response.json()["detail"]
    with env.session() as s:
        assert s.execute(text("SELECT state FROM samples")).scalar_one() == "in_review"


def test_heuristic_accepts_good_prediction_fits(env, h):
    ids = h.seed(env, frames=2, cameras=3, state="fitting")
    h.record_fit(env, ids[0], prediction=GOOD)
    h.record_fit(env, ids[1], prediction={"confidences": [0.7] * 21})  # mean not above 0.8
    with env.session() as s:
        states = dict(s.execute(text("SELECT id, state FROM samples")).all())
        members = s.execute(text("SELECT sample_id, stream FROM round_members")).all()
    assert states == {ids[0]: "accepted", ids[1]: "fitted"}
    assert members == [(ids[0], "heuristic")]


def test_review_queue_build_follows_the_policy(env, h):
    ids = h.seed(env, frames=6, cameras=1, state="fitting", fps=2.0)  # frames 0.5 s apart
    confidences = [0.50, 0.55, 0.60, 0.65, 0.70, 0.75]
    for sid, c in zip(ids, confidences, strict=True):
        h.record_fit(env, sid, prediction={"confidences": [c] * 21}, articulation=0.0 if c == 0.75 else 1.0)
    response = env.client.post("/api/admin/rounds/review-queue", headers=env.headers(Role.admin))
    assert response.status_code == 200, response.text
    # median 0.625 -> 0.65, 0.70, 0.75 kept; 0.75 is a flat hand; 0.70 first, 0.65 dropped: 0.5 s from it (the
    # default fixed policy; with review_capacity_per_round the gap only orders: test_verification_policy.py)
    assert response.json()["queued"] == [ids[4]]
    assert h.next_task(env, Role.reviewer, "review")["sample_id"] == ids[4]
    accepted = env.client.post(f"/api/review/samples/{ids[4]}/decision", json={"decision": "accept"},
                               headers=env.headers(Role.reviewer))
    assert accepted.json()["stream"] == "manual"
