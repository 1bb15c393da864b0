"""Proposals for annotators and overlays for reviewers, on a real (synthetic) capture whose ground truth
says where everything must land."""

from __future__ import annotations

import numpy as np

from backend.models.enums import Role


def test_review_overlay_puts_a_true_fit_on_the_clicks(sqlite_env, ui, ui_capture):
    env = sqlite_env
    task = ui.in_review(env, ui_capture)
    response = env.client.get(f"/api/review/samples/{task['sample_id']}/overlay", headers=env.headers(Role.reviewer))
    assert response.status_code == 200, response.text
    data = response.json()
    assert data["hand_model"] == {"model_file": "handloop-builtin v1", "stand_in": True,
                                  "label": "built-in stand-in hand, not MANO"}
    _, gt = ui.ground_truth(ui_capture, task["frame_index"])
    by_camera = {name: c for c, name in enumerate(gt.camera_names)}
    assert len(data["views"]) == len(task["views"])
    for view in data["views"]:
        truth = gt.keypoints_2d[by_camera[view["camera"]]]
        projected = np.array([p if p is not None else [np.nan, np.nan] for p in view["fit_keypoints_px"]])
        np.testing.assert_allclose(projected, truth, atol=0.05)  # the fit is the truth: same pixels
        assert view["iou"] == 0.9
        if view["clicks"]:
            assert view["mean_residual_px"] is not None and view["mean_residual_px"] < 0.05
    assert data["fit"]["source"] == "annotations" and data["fit"]["residual_reference"] == "clicks"
    # The mesh rebuilt from the parameters lands on the stored keypoints (same conventions as the synth).
    assert data["mesh"]["num_vertices"] > 100 and data["fit"]["mesh_keypoint_offset_mm"] < 0.5
    vertices = np.frombuffer(__import__("base64").b64decode(data["mesh"]["vertices_f32"]), "<f4").reshape(-1, 3)
    np.testing.assert_allclose(vertices, gt.vertices, atol=1e-4)
    assert data["scene_path"].startswith(f"/api/viewer/samples/{task['sample_id']}/scene?ticket=")


def test_residuals_grow_with_a_shifted_fit(sqlite_env, ui, ui_capture):
    env = sqlite_env
    task = ui.in_review(env, ui_capture, offset_m=0.01)
    data = env.client.get(f"/api/review/samples/{task['sample_id']}/overlay?mesh=false",
                          headers=env.headers(Role.reviewer)).json()
    assert data["mesh"] is None and data["mesh_note"] == "not requested"
    assert data["fit"]["mean_residual_px"] > 0.5  # 1 cm at ~1 m with f ~ 100 px: about a pixel or more


def test_residuals_keep_points_accepted_from_proposals_apart_from_clicks(sqlite_env, ui, ui_capture):
    # Clicked points exact, accepted proposals 3 px off: together they would read as one middling figure.
    import uuid

    env = sqlite_env
    ui.import_capture(env, ui_capture)
    task = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
    clicks = ui.clicks_from_truth(task, ui_capture)
    accepted_views = {v["id"] for v in task["views"][:4]}
    for click in clicks:
        if click["view_id"] in accepted_views and click["visibility"] == "visible":
            click.update(x=click["x"] + 3.0 if click["x"] < task["views"][0]["width"] - 4 else click["x"] - 3.0,
                         from_proposal=True)
    body = {"submission_id": uuid.uuid4().hex, "lease_token": task["lease_token"], "time_spent_s": 30.0,
            "clicks": clicks}
    submitted = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body,
                                headers=env.headers(Role.annotator))
    assert submitted.status_code == 201, submitted.text
    ui.record_truth_fit(env, task["sample_id"], task["frame_index"], ui_capture, submitted.json()["id"])
    review = env.client.post("/api/review/next", headers=env.headers(Role.reviewer)).json()
    data = env.client.get(f"/api/review/samples/{review['sample_id']}/overlay?mesh=false",
                          headers=env.headers(Role.reviewer)).json()
    split = data["fit"]["residual_by_origin"]
    n_accepted = sum(1 for c in clicks if c.get("from_proposal"))
    n_clicked = sum(1 for c in clicks if c["visibility"] == "visible") - n_accepted
    assert (split["accepted"]["n"], split["clicked"]["n"]) == (n_accepted, n_clicked) and n_accepted and n_clicked
    assert split["clicked"]["mean_px"] < 0.05 and abs(split["accepted"]["mean_px"] - 3.0) < 0.05
    shown = [c for view in data["views"] for c in view["clicks"]]
    assert sum(c["from_proposal"] for c in shown) == n_accepted  # the page can draw them as what they are


def test_overlay_needs_the_review_lease(sqlite_env, ui, ui_capture):
    env = sqlite_env
    task = ui.in_review(env, ui_capture)
    response = env.client.get(f"/api/review/samples/{task['sample_id']}/overlay", headers=env.headers(Role.admin))
    assert response.status_code == 403 and "lease" in response.json()["detail"]
    response = env.client.get("/api/review/samples/999999/overlay", headers=env.headers(Role.reviewer))
    assert response.status_code == 404


def test_proposals_offer_the_fit_and_the_reviewer_note_after_a_send_back(sqlite_env, ui, ui_capture):
    env = sqlite_env
    task = ui.in_review(env, ui_capture)
    sid = task["sample_id"]
    response = env.client.post(f"/api/review/samples/{sid}/decision", headers=env.headers(Role.reviewer),
                               json={"decision": "annotate", "reason": "thumb tip on the index"})
    assert response.status_code == 201, response.text
    again = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
    assert again["sample_id"] == sid
    response = env.client.get(f"/api/annotate/samples/{sid}/proposals", headers=env.headers(Role.annotator))
    assert response.status_code == 200, response.text
    data = response.json()
    assert data["review_note"] == "thumb tip on the index"
    assert [s["kind"] for s in data["sources"]] == ["fit"] and "not MANO" in data["sources"][0]["label"]
    assert len(data["cameras"]) == len(again["views"]) and data["keypoints_to_click"] == [0, 4, 8, 12, 16, 20]
    assert len(data["previous_clicks"]) == 6 * len(again["views"])
    camera = data["cameras"][0]
    assert set(camera) == {"view_id", "camera", "width", "height", "K", "dist", "R", "t"}


def test_proposals_need_the_annotation_lease(sqlite_env, ui, ui_capture):
    env = sqlite_env
    ui.import_capture(env, ui_capture)
    task = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
    response = env.client.get(f"/api/annotate/samples/{task['sample_id']}/proposals",
                              headers=env.headers(Role.reviewer))
    assert response.status_code == 403 and "lease" in response.json()["detail"]
    mine = env.client.get(f"/api/annotate/samples/{task['sample_id']}/proposals", headers=env.headers(Role.annotator))
    assert mine.status_code == 200 and mine.json()["sources"] == [] and mine.json()["review_note"] is None
