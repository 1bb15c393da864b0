"""The reviewer's discard (the paper's "discarding the sample"): a fit from predictions leaves the review queue and
the sample waits in the pool for the next round's fit; a fit from annotators' clicks is never discarded."""

from __future__ import annotations

from sqlalchemy import text

from backend.models.enums import Role


def _queued_prediction_fit(env, h) -> int:
    (sample_id,) = h.seed(env, frames=1, cameras=1, state="fitting")
    h.record_fit(env, sample_id, prediction={"confidences": [0.7] * 21}, articulation=1.0)  # the heuristic declines
    queued = env.client.post("/api/admin/rounds/review-queue", headers=env.headers(Role.admin)).json()["queued"]
    assert queued == [sample_id]
    return sample_id


def _discard(env, sample_id, **body):
    return env.client.post(f"/api/review/samples/{sample_id}/decision", json={"decision": "discard", **body},
                           headers=env.headers(Role.reviewer))


def test_discard_returns_the_sample_to_the_pool_until_a_new_fit(env, h):
    sample_id = _queued_prediction_fit(env, h)
    task = h.next_task(env, Role.reviewer, "review")
    assert task["sample_id"] == sample_id and task["fit"]["from_annotation"] is False
    response = _discard(env, sample_id)  # no reason needed: the quick "not good enough"
    assert response.status_code == 201, response.text
    assert response.json()["state"] == "fitted" and response.json()["stream"] is None
    # Not offered again this round: a rebuilt queue skips the discarded fit, and the reviewer queue is empty.
    rebuilt = env.client.post("/api/admin/rounds/review-queue", headers=env.headers(Role.admin))
    assert rebuilt.json()["queued"] == []
    assert env.client.post("/api/review/next", headers=env.headers(Role.reviewer)).status_code == 204
    with env.session() as s:
        assert s.execute(text("SELECT decision FROM decisions")).scalars().all() == ["discard"]
        assert s.execute(text("SELECT count(*) FROM round_members")).scalar_one() == 0
    # The admin's round statistics count it (the rounds table's "reviewers decided").
    stats = env.client.get("/api/admin/rounds/statistics", headers=env.headers(Role.admin)).json()
    assert [r["decisions"] for r in stats["rounds"]] == [{"accept": 0, "discard": 1, "annotate": 0, "reject": 0}]
    assert stats["rounds"][0]["added_total"] == 0
    # The next round's fit of the same sample is a new candidate.
    with env.session() as s:
        s.execute(text("UPDATE samples SET state = 'fitting' WHERE id = :id"), {"id": sample_id})
        s.commit()
    h.record_fit(env, sample_id, prediction={"confidences": [0.7] * 21}, articulation=1.0)
    rebuilt = env.client.post("/api/admin/rounds/review-queue", headers=env.headers(Role.admin))
    assert rebuilt.json()["queued"] == [sample_id]


def test_a_fit_from_clicks_is_not_discarded_and_nothing_is_written(env, h):
    (sample_id,) = h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    submitted = env.client.post(f"/api/annotate/samples/{sample_id}/submissions", json=h.body(task),
                                headers=env.headers(Role.annotator))
    assert submitted.status_code == 201
    h.record_fit(env, sample_id, from_clicks=True)
    task = h.next_task(env, Role.reviewer, "review")
    assert task["fit"]["from_annotation"] is True
    response = _discard(env, sample_id, reason="not quite")
    assert response.status_code == 409
    assert "annotators' clicks" in response.json()["detail"] and "send it back" in response.json()["detail"]
    with env.session() as s:
        assert s.execute(text("SELECT count(*) FROM decisions")).scalar_one() == 0
        assert s.execute(text("SELECT state FROM samples")).scalar_one() == "in_review"


def test_reject_and_annotate_still_need_a_reason_discard_does_not(env, h):
    sample_id = _queued_prediction_fit(env, h)
    h.next_task(env, Role.reviewer, "review")
    for decision in ("reject", "annotate"):
        response = env.client.post(f"/api/review/samples/{sample_id}/decision", json={"decision": decision},
                                   headers=env.headers(Role.reviewer))
        assert response.status_code == 422 and "needs a reason" in response.json()["detail"]
    assert _discard(env, sample_id, reason="fingers slightly off").status_code == 201
