"""No hand (per view, with the submission; per sample), skip with a reason, and failed fits (issue 38): each
stored with its reason and counted; a sample someone skipped or whose fit failed on their work goes to someone
else; the page is told why a fit failed; a fit's proposals carry its agreement as confidence."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import text

from backend.models.enums import Role
from backend.services.display.fit_agreement import ZERO_CONF_PX, fit_confidences


def _flags(env) -> list:
    with env.session() as s:
        return s.execute(text("SELECT sample_id, view_id, user_id, kind, reason FROM annotation_flags"
                              " ORDER BY id")).all()


def test_no_hand_views_go_with_the_submission_and_must_hold_no_point(env, h):
    ids = h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    v0, v1 = (v["id"] for v in task["views"])
    body = h.body(task)
    url = f"/api/annotate/samples/{ids[0]}/submissions"
    placed_there = env.client.post(url, json={**body, "no_hand_views": [v0]}, headers=env.headers(Role.annotator))
    assert placed_there.status_code == 422 and f"view {v0}, which is marked 'no hand here'" in placed_there.text
    unknown = env.client.post(url, json={**body, "no_hand_views": [999999]}, headers=env.headers(Role.annotator))
    assert unknown.status_code == 422 and "no_hand_views[0]: view 999999 is not a view" in unknown.text
    assert h.count(env, "submissions") == 0 and h.count(env, "annotation_flags") == 0
    body["clicks"] = [c if c["view_id"] == v1 else {"view_id": v0, "keypoint": c["keypoint"],
                                                      "visibility": "not_annotated"} for c in body["clicks"]]
    ok = env.client.post(url, json={**body, "no_hand_views": [v0]}, headers=env.headers(Role.annotator))
    assert ok.status_code == 201, ok.text
    assert _flags(env) == [(ids[0], v0, env.user_ids[Role.annotator], "no_hand_view", "")]


def test_an_all_not_annotated_submission_is_refused(env, h):
    ids = h.seed(env, frames=1, cameras=2)
    task = h.next_task(env)
    clicks = [{"view_id": v["id"], "keypoint": k, "visibility": "not_annotated"} for v in task["views"]
              for k in task["keypoints_to_click"]]
    r = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task, clicks=clicks),
                        headers=env.headers(Role.annotator))
    assert r.status_code == 422 and "nothing to fit" in r.text
    assert h.count(env, "submissions") == 0 and h.count(env, "jobs") == 0


def test_skip_needs_a_reason_and_sends_the_sample_to_someone_else(env, h):
    ids = h.seed(env, frames=2, cameras=1)
    task = h.next_task(env)
    url = f"/api/annotate/samples/{ids[0]}/skip"
    blank = env.client.post(url, json={"kind": "skip", "reason": "  ", "lease_token": task["lease_token"]},
                            headers=env.headers(Role.annotator))
    assert blank.status_code == 422 and "needs a reason" in blank.text
    r = env.client.post(url, json={"kind": "skip", "reason": "too blurred", "lease_token": task["lease_token"]},
                        headers=env.headers(Role.annotator))
    assert r.status_code == 200 and r.json() == {"sample_id": ids[0], "kind": "skip", "state": "needs_annotation"}
    assert h.next_task(env)["sample_id"] == ids[1]  # not back to the one who skipped it
    assert h.next_task(env, Role.reviewer)["sample_id"] == ids[0]  # someone else gets it
    assert _flags(env) == [(ids[0], None, env.user_ids[Role.annotator], "skip", "too blurred")]
    flags = env.client.get("/api/admin/dashboard", headers=env.headers(Role.admin)).json()["flags"]
    assert flags == {"no_hand_view": 0, "no_hand": 0, "skip": 1, "fit_failed": 0}
    again = env.client.post(url, json={"kind": "skip", "reason": "x"}, headers=env.headers(Role.annotator))
    assert again.status_code in (403, 409)  # no lease on it any more


def test_no_hand_takes_the_sample_out_of_the_queue(env, h):
    ids = h.seed(env, frames=1, cameras=1)
    task = h.next_task(env)
    r = env.client.post(f"/api/annotate/samples/{ids[0]}/skip", json={"kind": "no_hand", "reason": "empty desk",
                        "lease_token": task["lease_token"]}, headers=env.headers(Role.annotator))
    assert r.status_code == 200 and r.json()["state"] == "rejected"
    assert env.client.post("/api/annotate/next", headers=env.headers(Role.reviewer)).status_code == 204


def test_a_failed_fit_is_told_to_its_author_and_the_sample_goes_to_someone_else(env, h):
    from workers.tasks import records

    ids = h.seed(env, frames=2, cameras=2)
    task = h.next_task(env)
    r = env.client.post(f"/api/annotate/samples/{ids[0]}/submissions", json=h.body(task),
                        headers=env.headers(Role.annotator))
    assert r.status_code == 201
    with env.session() as session, session.begin():
        records.record_fit_failure(session, ids[0], r.json()["fit_job_id"], "inputs: the fit diverged")
    failures = env.client.get("/api/annotate/fit-failures", headers=env.headers(Role.annotator)).json()
    assert [(f["sample_id"], f["submission_id"], f["reason"]) for f in failures] == [
        (ids[0], r.json()["id"], "inputs: the fit diverged")]
    assert env.client.get("/api/annotate/fit-failures", headers=env.headers(Role.reviewer)).json() == []
    assert h.next_task(env)["sample_id"] == ids[1]  # not the sample its fit failed on, in a loop
    other = h.next_task(env, Role.reviewer)
    assert other["sample_id"] == ids[0]
    proposals = env.client.get(f"/api/annotate/samples/{ids[0]}/proposals", headers=env.headers(Role.reviewer)).json()
    assert proposals["fit_failure"]["reason"] == "inputs: the fit diverged"
    assert len(proposals["previous_clicks"]) == 12  # the points are kept, not rewritten


def test_fit_confidence_is_its_agreement_with_what_it_was_fitted_to():
    fit_px = {1: np.zeros((21, 2)), 2: np.zeros((21, 2))}
    fit_px[2][5] = np.nan
    observed = {1: {0: (0.0, 0.0), 5: (3.0, 4.0), 7: (ZERO_CONF_PX * 2, 0.0)}, 2: {0: (0.0, 6.0), 5: (1.0, 1.0)}}
    conf = fit_confidences(fit_px, observed)
    assert conf[0] == pytest.approx(1 - 3.0 / ZERO_CONF_PX, abs=1e-4)  # median of 0 and 6 px
    assert conf[5] == pytest.approx(1 - 5.0 / ZERO_CONF_PX, abs=1e-4)  # view 2 cannot project it
    assert conf[7] == 0.0 and conf[1] is None
