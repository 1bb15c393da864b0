"""Prefetch leases the task after the one on screen; it is an ordinary lease that `next` hands back."""

from __future__ import annotations

from backend.models.enums import Role


def _prefetch(env, current: int, role: Role = Role.annotator, queue: str = "annotate"):
    return env.client.post(f"/api/{queue}/prefetch", json={"current_sample_id": current}, headers=env.headers(role))


def test_prefetch_leases_another_sample_that_next_returns_after_submit(env, h):
    ids = h.seed(env, frames=4, cameras=2)
    first = h.next_task(env)
    ahead = _prefetch(env, first["sample_id"])
    assert ahead.status_code == 200, ahead.text
    second = ahead.json()
    assert second["sample_id"] != first["sample_id"] and second["sample_id"] in ids
    again = _prefetch(env, first["sample_id"]).json()  # asking again: the same prefetched lease, renewed
    assert again["sample_id"] == second["sample_id"] and again["lease_token"] == second["lease_token"]
    # Nobody else gets either sample.
    with env.session() as s:
        from sqlalchemy import text

        held = dict(s.execute(text("SELECT id, leased_by_id FROM samples WHERE leased_by_id IS NOT NULL")).all())
    assert held == {first["sample_id"]: env.user_ids[Role.annotator], second["sample_id"]: env.user_ids[Role.annotator]}
    other = env.client.post("/api/annotate/next", headers=env.headers(Role.reviewer)).json()
    assert other["sample_id"] not in (first["sample_id"], second["sample_id"])
    response = env.client.post(f"/api/annotate/samples/{first['sample_id']}/submissions", json=h.body(first),
                               headers=env.headers(Role.annotator))
    assert response.status_code == 201
    assert h.next_task(env)["sample_id"] == second["sample_id"]


def test_at_most_two_leases_are_held(env, h):
    h.seed(env, frames=5, cameras=1)
    first = h.next_task(env)
    second = _prefetch(env, first["sample_id"]).json()
    # Asking with the prefetched sample as current gives back the other held one, not a third.
    back = _prefetch(env, second["sample_id"]).json()
    assert back["sample_id"] == first["sample_id"]
    with env.session() as s:
        from sqlalchemy import text

        n = s.execute(text("SELECT count(*) FROM samples WHERE leased_by_id IS NOT NULL")).scalar_one()
    assert n == 2


def test_empty_queue_answers_204(env, h):
    h.seed(env, frames=1, cameras=1)
    first = h.next_task(env)
    assert _prefetch(env, first["sample_id"]).status_code == 204


def test_review_prefetch_follows_the_confidence_order(env, h):
    ids = h.seed(env, frames=3, cameras=1, state="in_review")
    with env.session() as s, s.begin():
        from sqlalchemy import text

        for sid, conf in zip(ids, (0.5, 0.9, 0.7), strict=True):
            s.execute(text("UPDATE samples SET confidence = :c WHERE id = :i"), {"c": conf, "i": sid})
    first = h.next_task(env, Role.reviewer, "review")
    assert first["sample_id"] == ids[1]
    ahead = _prefetch(env, first["sample_id"], Role.reviewer, "review")
    assert ahead.status_code == 200 and ahead.json()["sample_id"] == ids[2]


def test_prefetch_needs_the_current_sample(sqlite_env):
    response = sqlite_env.client.post("/api/annotate/prefetch", json={}, headers=sqlite_env.headers(Role.annotator))
    assert response.status_code == 422 and "current_sample_id" in response.json()["detail"]
    response = sqlite_env.client.post("/api/annotate/prefetch", json={"current_sample_id": -3},
                                      headers=sqlite_env.headers(Role.annotator))
    assert response.status_code == 422
