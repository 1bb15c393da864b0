"""The review page keeps the fit's distance to points placed by hand apart from its distance to points the
annotator accepted from proposals (a fit lands near the proposal it came from, so counted together they
flatter it), and draws accepted points as proposals. Real browser, real API, real worker (it fits)."""

from __future__ import annotations

import pytest

from tests.browser.conftest import sign_in
from tests.support.annotate import clicks_body, queue_for_annotation, wait_until

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_the_review_page_shows_residuals_to_clicks_apart_from_accepted_proposals(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    queue_for_annotation(stack, 1)
    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()
        body = clicks_body(stack, task)
        accepted_views = {v["id"] for v in task["views"][:3]}  # as if Enter had accepted these views' proposals
        for click in body["clicks"]:
            click["from_proposal"] = click["view_id"] in accepted_views and click["visibility"] == "visible"
        response = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body)
        assert response.status_code == 201, response.text
    with stack.client("admin") as http:
        wait_until(lambda: http.get("/api/admin/rounds/statistics").json()["samples_by_state"].get("in_review"),
                   300, "the fit of the annotated sample", stack)
    n_accepted = sum(1 for c in body["clicks"] if c["from_proposal"])
    n_clicked = sum(1 for c in body["clicks"] if c["visibility"] == "visible") - n_accepted
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    assert page.get_attribute("body", "data-sample") == str(task["sample_id"])
    clicked = page.inner_text(".review-side .residual-clicked")
    accepted = page.inner_text(".review-side .residual-accepted")
    assert f"over {n_clicked} points placed by hand" in clicked, clicked
    assert f"over {n_accepted} accepted proposals" in accepted, accepted
    banner = page.inner_text(".fit-banner")
    assert "vs clicks" in banner and "vs accepted proposals" in banner, banner
    t.shot("review-residuals-by-origin")
    assert not t.errors, t.errors


def test_the_review_page_measures_a_detector_fit_against_the_detector(live_stack, tab):
    # A pre-annotation fit (source "detector", no clicks) whose detections lie 3 px right of its keypoints in
    # every view: the page says how far the fit is from the detector, and that it is the detector.
    import numpy as np
    from sqlalchemy import select

    from backend.models.capture import Sample
    from backend.models.enums import SampleState
    from backend.services.captures.state_machine import transition
    from backend.services.display.view_geometry import view_cameras
    from backend.services.review.verification import HeuristicThresholds
    from workers.capture import read_capture
    from workers.capture.reader import load_ground_truth
    from workers.geometry.projection import project_visible as project
    from workers.tasks import records

    stack = live_stack(frames=2, worker=False, queue_for_annotation=False)
    capture = read_capture(stack.capture_dir, check_images=False)
    gt = load_ground_truth(capture.sequences[0].frames[0])
    factory = stack.session_factory()
    try:
        with factory.begin() as session:
            sample = session.execute(select(Sample).where(Sample.frame_index == 0)).scalar_one()
            sample.state = SampleState.fitting  # as the pre-annotation job leaves it for its fit job
            cameras = view_cameras(session, sample.id)
            right = np.array([3.0, 0.0])
            views = [{"view_id": cam.view_id, "keypoints_px": (project(gt.keypoints_3d, cam) + right).tolist(),
                      "scores": [0.9] * 21, "presence": 0.95} for cam in cameras]
            detection = {"view_ids": [cam.view_id for cam in cameras], "views": views,
                         "inliers": np.ones((21, len(cameras)), dtype=bool).tolist(),
                         "points_world": gt.keypoints_3d.tolist(), "confidence": [0.9] * 21, "frame_confidence": 0.9}
            params = gt.params.to_theta()
            records.record_fit(session, sample.id, params=params.tolist(), keypoints_m=gt.keypoints_3d.tolist(),
                               view_ious={cam.view_id: 0.9 for cam in cameras}, diagnostics={},
                               inputs={"source": "detector", "detection": detection},
                               model_file="handloop-builtin v1", thresholds=HeuristicThresholds())
            transition(session, sample, SampleState.in_review, None, reason="test")
            sample_id = sample.id
    finally:
        factory.kw["bind"].dispose()
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    assert page.get_attribute("body", "data-sample") == str(sample_id)
    banner = page.inner_text(".fit-banner")
    assert "mean residual 3.0 px (vs detector)" in banner, banner
    facts = page.inner_text(".review-side .residual-clicked")
    assert facts == "3.0 px mean, 3.0 max vs detector", facts
    assert "made from the detector's keypoints" in page.inner_text(".review-side .mvnet-note")
    t.shot("review-residuals-vs-detector")
    assert not t.errors, t.errors
