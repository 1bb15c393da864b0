"""Drafts: saved while a lease is held, restored to their author only, deleted on submit or decision;
lapsed leases re-taken while the sample is free; bad input refused with nothing written."""

from __future__ import annotations

from datetime import timedelta

from sqlalchemy import text

from backend.db.base import utcnow
from backend.models.enums import Role


def _draft(task: dict, **overrides: object) -> dict:
    view = task["views"][0]
    body = {"lease_token": task["lease_token"], "submission_id": "draft-submission-1", "time_spent_s": 4.5,
            "clicks": [{"view_id": view["id"], "keypoint": 0, "x": 10.0, "y": 12.0, "visibility": "visible"},
                       {"view_id": view["id"], "keypoint": 4, "x": 20.0, "y": 22.0, "visibility": "occluded"}],
            "view_index": 0, "keypoint": 8}
    body.update(overrides)
    return body


def _url(task: dict, queue: str = "annotate") -> str:
    return f"/api/{queue}/samples/{task['sample_id']}/draft"


def _lapse(env, sample_id: int) -> None:
    with env.session() as s, s.begin():
        s.execute(text("UPDATE samples SET lease_expires_at = :t WHERE id = :i"),
                  {"t": utcnow() - timedelta(seconds=5), "i": sample_id})


def test_a_draft_is_restored_to_its_author_and_counts_revisions(env, h):
    h.seed(env, frames=2, cameras=2)
    task = h.next_task(env)
    headers = env.headers(Role.annotator)
    assert env.client.get(_url(task), headers=headers).status_code == 204
    first = env.client.put(_url(task), json=_draft(task), headers=headers)
    assert first.status_code == 200, first.text
    second = env.client.put(_url(task), json=_draft(task, keypoint=12), headers=headers)
    assert (first.json()["revision"], second.json()["revision"]) == (1, 2)
    got = env.client.get(_url(task), headers=headers).json()
    assert got["payload"]["keypoint"] == 12 and len(got["payload"]["clicks"]) == 2
    assert got["payload"]["clicks"][1]["visibility"] == "occluded" and "lease_token" not in got["payload"]
    assert got["payload"]["submission_id"] == "draft-submission-1" and h.count(env, "drafts") == 1


def test_next_returns_the_drafted_sample_of_the_two_held(env, h):
    h.seed(env, frames=3, cameras=1)
    headers = env.headers(Role.annotator)
    task = h.next_task(env)
    ahead = env.client.post("/api/annotate/prefetch", json={"current_sample_id": task["sample_id"]}, headers=headers)
    assert ahead.status_code == 200
    ahead = ahead.json()
    # Work on the prefetched sample (as after submitting the first), then a reload: next shows that work.
    assert env.client.put(_url(ahead), json=_draft(ahead), headers=headers).status_code == 200
    assert h.next_task(env)["sample_id"] == ahead["sample_id"]


def test_submit_deletes_the_draft(env, h):
    h.seed(env, frames=2, cameras=2)
    task = h.next_task(env)
    headers = env.headers(Role.annotator)
    env.client.put(_url(task), json=_draft(task), headers=headers)
    response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=h.body(task),
                               headers=headers)
    assert response.status_code == 201, response.text
    assert h.count(env, "drafts") == 0


def test_work_left_on_a_lapsed_lease_travels_to_the_next_holder(env, h):
    """Issue 38 item 4 (this test said the opposite before: the next holder started at 0 and redid the points):
    the work left on a lapsed lease goes with the sample to whoever takes it next, naming who left it."""
    h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    env.client.put(_url(task), json=_draft(task), headers=env.headers(Role.annotator))
    _lapse(env, task["sample_id"])
    other = h.next_task(env, Role.admin)  # the lapsed sample goes to someone else
    assert other["sample_id"] == task["sample_id"]
    got = env.client.get(_url(other), headers=env.headers(Role.admin))
    assert got.status_code == 200, got.text
    assert got.json()["left_by"]  # who left it (their name, else their email)
    assert [(c["keypoint"], c["x"], c["visibility"]) for c in got.json()["payload"]["clicks"]] == [
        (0, 10.0, "visible"), (4, 20.0, "occluded")]
    # The new holder's own saves are theirs (no conflict with the work they were handed), and read back as such.
    mine = env.client.put(_url(other), json=_draft(other, base_revision=got.json()["revision"], writer="adminTab",
                                                     keypoint=12), headers=env.headers(Role.admin))
    assert mine.status_code == 200, mine.text
    again = env.client.get(_url(other), headers=env.headers(Role.admin)).json()
    assert again["left_by"] is None and again["payload"]["keypoint"] == 12
    # ... and its author, no longer holding the lease, cannot read or overwrite it.
    refused = env.client.get(_url(task), headers=env.headers(Role.annotator))
    assert refused.status_code == 403 and "no annotate lease" in refused.json()["detail"]
    assert env.client.put(_url(task), json=_draft(task), headers=env.headers(Role.annotator)).status_code == 403


def test_bad_drafts_are_refused_and_write_nothing(env, h):
    h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    headers = env.headers(Role.annotator)
    view = task["views"][0]
    cases = {
        "wrong view": (_draft(task, clicks=[{"view_id": 999999, "keypoint": 0, "x": 1.0, "y": 1.0}]), 422,
                       "not a view of sample"),
        "outside the image": (_draft(task, clicks=[{"view_id": view["id"], "keypoint": 0, "x": 1e5, "y": 1.0}]),
                              422, "outside"),
        "twice": (_draft(task, clicks=[{"view_id": view["id"], "keypoint": 0, "x": 1.0, "y": 1.0}] * 2), 422,
                  "given twice"),
        "mask size": (_draft(task, masks=[{"view_id": view["id"], "width": 3, "height": 3, "rle": [9]}]), 422,
                      "mask is 3x3"),
        "unknown field": ({**_draft(task), "extra": 1}, 422, "extra"),
        "wrong token": (_draft(task, lease_token="not-the-token"), 403, "does not match"),
        "no token": ({k: v for k, v in _draft(task).items() if k != "lease_token"}, 422, "lease_token"),
        "keypoint range": (_draft(task, keypoint=21), 422, "keypoint"),
    }
    for name, (body, status, words) in cases.items():
        response = env.client.put(_url(task), json=body, headers=headers)
        assert response.status_code == status, (name, response.text)
        assert words in response.text, (name, response.text)
    nan = env.client.put(_url(task), content=b'{"lease_token": "x", "submission_id": "abcdefgh", "time_spent_s": NaN}',
                         headers={**headers, "Content-Type": "application/json"})
    assert nan.status_code == 422
    assert env.client.put("/api/annotate/samples/999999/draft", json=_draft(task), headers=headers).status_code == 404
    assert h.count(env, "drafts") == 0


def test_discard_deletes_only_your_own_draft(env, h):
    h.seed(env, frames=1, cameras=1)
    task = h.next_task(env)
    env.client.put(_url(task), json=_draft(task), headers=env.headers(Role.annotator))
    assert env.client.delete(_url(task), headers=env.headers(Role.admin)).status_code == 204
    assert h.count(env, "drafts") == 1
    assert env.client.delete(_url(task), headers=env.headers(Role.annotator)).status_code == 204
    assert h.count(env, "drafts") == 0


def test_a_lapsed_lease_is_retaken_with_its_token_while_the_sample_is_free(env, h):
    h.seed(env, frames=1, cameras=1)
    task = h.next_task(env)
    headers = env.headers(Role.annotator)
    env.client.put(_url(task), json=_draft(task), headers=headers)
    _lapse(env, task["sample_id"])
    renew = env.client.post(f"/api/annotate/samples/{task['sample_id']}/lease/renew",
                            json={"lease_token": task["lease_token"]}, headers=headers)
    assert renew.status_code == 409 and "expired" in renew.json()["detail"]
    retaken = env.client.post(f"/api/annotate/samples/{task['sample_id']}/lease/retake",
                              json={"lease_token": task["lease_token"]}, headers=headers)
    assert retaken.status_code == 200, retaken.text
    assert retaken.json()["lease_token"] == task["lease_token"]  # the draft and the page keep working
    assert env.client.get(_url(task), headers=headers).json()["revision"] == 1
    with env.session() as s:
        assert s.execute(text("SELECT count(*) FROM audit_events WHERE action = 'lease.retake'")).scalar_one() == 1


def test_retake_is_refused_when_someone_else_holds_the_sample_or_it_left_the_queue(env, h):
    ids = h.seed(env, frames=2, cameras=1)
    task = h.next_task(env)
    assert env.client.put(_url(task), json=_draft(task), headers=env.headers(Role.annotator)).status_code == 200
    _lapse(env, task["sample_id"])
    assert h.next_task(env, Role.admin)["sample_id"] == task["sample_id"]
    url = f"/api/annotate/samples/{task['sample_id']}/lease/retake"
    refused = env.client.post(url, json={"lease_token": task["lease_token"]}, headers=env.headers(Role.annotator))
    assert refused.status_code == 409 and "given to someone else" in refused.json()["detail"]
    # Issue 38 item 12: someone who never held the lease is not told about "your lease".
    for body in ({}, {"lease_token": "never-mine-0123456789"}):
        stranger = env.client.post(url, json=body, headers=env.headers(Role.reviewer))
        assert stranger.status_code == 409, stranger.text
        assert "your lease" not in stranger.json()["detail"] and "someone else" in stranger.json()["detail"]
    h.set_state(env, [ids[1]], "fitting")
    gone = env.client.post(f"/api/annotate/samples/{ids[1]}/lease/retake", json={}, headers=env.headers(Role.annotator))
    assert gone.status_code == 409 and "'fitting'" in gone.json()["detail"]


def test_a_reviewers_note_is_kept_until_the_decision(env, h):
    ids = h.seed(env, frames=1, cameras=1)
    h.set_state(env, ids, "fitting")
    h.record_fit(env, ids[0], ious=0.1)  # a poor fit: left for a reviewer
    h.set_state(env, ids, "in_review")
    task = h.next_task(env, Role.reviewer, "review")
    headers = env.headers(Role.reviewer)
    note = {"lease_token": task["lease_token"], "decision": "reject", "reason": "thumb on the wrong finger"}
    assert env.client.put(_url(task, "review"), json=note, headers=headers).status_code == 200
    assert env.client.put(_url(task, "review"), json={**note, "reason": "x" * 2001},
                          headers=headers).status_code == 422
    got = env.client.get(_url(task, "review"), headers=headers).json()
    assert got["payload"] == {"decision": "reject", "reason": "thumb on the wrong finger", "time_spent_s": 0.0}
    decided = env.client.post(f"/api/review/samples/{ids[0]}/decision",
                              json={"decision": "reject", "reason": "wrong finger", "lease_token": task["lease_token"]},
                              headers=headers)
    assert decided.status_code == 201, decided.text
    assert h.count(env, "drafts") == 0


def test_after_a_lapse_next_gives_back_the_sample_with_your_draft_first(env, h):
    ids = h.seed(env, frames=3, cameras=1)
    h.next_task(env)  # sample 1, left untouched
    headers = env.headers(Role.annotator)
    ahead = env.client.post("/api/annotate/prefetch", json={"current_sample_id": ids[0]}, headers=headers).json()
    env.client.put(_url(ahead), json=_draft(ahead), headers=headers)
    for sample_id in ids[:2]:
        _lapse(env, sample_id)
    again = h.next_task(env)  # both lapsed and free: the one with the work comes back, not the queue's first
    assert again["sample_id"] == ahead["sample_id"] == ids[1]
    assert env.client.get(_url(again), headers=headers).json()["revision"] == 1


def test_two_pages_saving_one_draft_the_second_is_told(env, h):
    """Issue 38 item 3: two tabs on one sample; the save made on an older revision by the other tab is refused
    (409, nothing written), so the point placed in one tab never vanishes silently; the page reads the other."""
    h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    headers = env.headers(Role.annotator)
    view = task["views"][0]
    first = env.client.put(_url(task), json=_draft(task, base_revision=0, writer="tabA"), headers=headers)
    assert first.status_code == 200 and first.json()["revision"] == 1
    assert "base_revision" not in first.json()["payload"] and first.json()["payload"]["writer"] == "tabA"
    # Tab B opened the sample at revision 1; both go on working.
    b = env.client.put(_url(task), json=_draft(task, base_revision=1, writer="tabB", keypoint=12), headers=headers)
    assert b.status_code == 200 and b.json()["revision"] == 2
    a_point = {"view_id": view["id"], "keypoint": 8, "x": 30.0, "y": 31.0, "visibility": "visible"}
    a = env.client.put(_url(task), json=_draft(task, base_revision=1, writer="tabA",
                                               clicks=_draft(task)["clicks"] + [a_point]), headers=headers)
    assert a.status_code == 409, a.text
    assert "another tab or window (revision 2)" in a.json()["detail"] and "nothing was written" in a.json()["detail"]
    stored = env.client.get(_url(task), headers=headers).json()
    assert stored["revision"] == 2 and stored["payload"]["writer"] == "tabB"
    # Tab A chose its own work, seen both: saved on the revision it was shown.
    kept = env.client.put(_url(task), json=_draft(task, base_revision=2, writer="tabA",
                                                  clicks=_draft(task)["clicks"] + [a_point]), headers=headers)
    assert kept.status_code == 200 and kept.json()["revision"] == 3 and len(kept.json()["payload"]["clicks"]) == 3
    # A page's own earlier save answering late (a resend as it goes) is no conflict.
    again = env.client.put(_url(task), json=_draft(task, base_revision=2, writer="tabA"), headers=headers)
    assert again.status_code == 200 and again.json()["revision"] == 4
    # Without a base revision (older pages), the last save wins as before.
    assert env.client.put(_url(task), json=_draft(task), headers=headers).status_code == 200
    bad = env.client.put(_url(task), json=_draft(task, base_revision=-1), headers=headers)
    assert bad.status_code == 422 and "base_revision" in bad.json()["detail"]
