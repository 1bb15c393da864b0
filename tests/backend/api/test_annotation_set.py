"""POST /api/admin/samples/queue-for-annotation: an admin picks unlabeled samples for the annotators."""

from __future__ import annotations

from sqlalchemy import text

from backend.models.enums import Role


def test_chosen_unlabeled_samples_join_the_annotator_queue(env, h):
    ids = h.seed(env, frames=5, cameras=1, state="unlabeled")
    admin = env.headers(Role.admin)
    response = env.client.post("/api/admin/samples/queue-for-annotation", headers=admin,
                               json={"sample_ids": [ids[3], ids[1], ids[3]]})
    assert response.status_code == 200, response.text
    assert response.json() == {"queued": [ids[3], ids[1]]}
    task = h.next_task(env)
    assert task["sample_id"] == ids[1]  # capture order within the queue
    with env.session() as s:
        states = dict(s.execute(text("SELECT id, state FROM samples")).all())
    assert [states[i] for i in ids] == ["unlabeled", "needs_annotation", "unlabeled", "needs_annotation", "unlabeled"]


def test_it_is_all_or_nothing_with_clear_errors(env, h):
    ids = h.seed(env, frames=3, cameras=1, state="unlabeled")
    h.set_state(env, [ids[2]], "accepted")
    admin = env.headers(Role.admin)
    refused = env.client.post("/api/admin/samples/queue-for-annotation", headers=admin,
                              json={"sample_ids": [ids[0], ids[2]]})
    assert refused.status_code == 409 and f"{ids[2]} is 'accepted'" in refused.json()["detail"]
    missing = env.client.post("/api/admin/samples/queue-for-annotation", headers=admin,
                              json={"sample_ids": [ids[0], 999_999]})
    assert missing.status_code == 404 and "999999" in missing.json()["detail"]
    for body in ({"sample_ids": []}, {"sample_ids": [0]}, {"sample_ids": ["x"]}, {"ids": [1]}):
        assert env.client.post("/api/admin/samples/queue-for-annotation", headers=admin, json=body).status_code == 422
    assert env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).status_code == 204
