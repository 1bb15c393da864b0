"""Proposals with guard rails, in a real browser on a live API: each shows its source and confidence; Enter
accepts only the confident ones and leaves the rest ringed for a look; a point placed by hand re-projects
the proposals accepted in the other views (one undo step); accepted keypoints are submitted as
proposals, not clicks; epipolar curves guide the placement in another view."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sqlalchemy import text

from tests.browser.conftest import KEYPOINT, SAMPLE, SCREEN_OF, sign_in, submit_as_is
from tests.support.annotate import ground_truth_of

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CLICK = "([v, k]) => { const p = window.__handloop.page; return p.annotation.get(p.views[v].id, k); }"
OFFSET_PX = 3.0
CONFIDENCES = {0: 0.95, 4: 0.45, 8: 0.2, 12: 0.9, 16: 0.9, 20: 0.9}  # thumb: shown, not accepted; index: hidden


def test_enter_accepts_only_confident_proposals_and_a_click_reprojects_the_accepted(live_stack, tab):
    stack = live_stack(worker=False)
    t = tab()
    page = t.page
    state: dict = {}

    def with_mvnet(route) -> None:
        # The API's answer plus an MVNet source: the true keypoints 3 px off, with chosen confidences.
        response = route.fetch()
        body = response.json()
        gt = state["gt"]
        names = list(gt.camera_names)
        views = {}
        for camera in body["cameras"]:
            uv = gt.keypoints_2d[names.index(camera["camera"])]
            views[str(camera["view_id"])] = [[float(x) + OFFSET_PX, float(y)] for x, y in uv]
        conf = [CONFIDENCES.get(k, 0.9) for k in range(21)]
        body["sources"].append({"kind": "mvnet", "label": "MVNet (test)", "confidences": conf, "views": views})
        route.fulfill(response=response, body=json.dumps(body))

    user = stack.users["annotator"]
    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()  # the task the page will show (the lease is reused)
    state["gt"] = gt = ground_truth_of(stack, task)
    names = list(gt.camera_names)
    page.route("**/proposals", with_mvnet)
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    assert page.evaluate(SAMPLE) == task["sample_id"]
    cam = [names.index(v["camera"]) for v in task["views"]]
    truth = lambda v, k: gt.keypoints_2d[cam[v], k]  # noqa: E731

    # View 1: the proposals show source and confidence; Enter takes the four confident ones only.
    side = page.inner_text(".kp-list")
    assert "M 0.95" in side and "M 0.45 · look" in side and "M 0.20" not in side, side
    page.keyboard.press("Enter")
    assert [page.evaluate(CLICK, [0, k]) is not None for k in (0, 4, 8, 12, 16, 20)] == [
        True, False, False, True, True, True]
    assert page.evaluate(KEYPOINT) == 4  # on the doubtful one, for a look
    page.mouse.click(*page.evaluate(SCREEN_OF, truth(0, 4).tolist()))  # the thumb, placed by hand
    assert "from" not in page.evaluate(CLICK, [0, 4])
    accepted_wrist = page.evaluate(CLICK, [0, 0])
    assert accepted_wrist["from"] == "mvnet"
    np.testing.assert_allclose([accepted_wrist["x"], accepted_wrist["y"]], truth(0, 0) + np.array([OFFSET_PX, 0.0]),
                               atol=1e-6)

    # The wrist by hand in views 2 and 3: the wrist accepted in view 1 moves onto their triangulation.
    for v in (1, 2):
        page.click(f".thumb >> nth={v}")
        page.keyboard.press("1")
        if v == 2:  # while placing it: the epipolar curve of view 2's wrist is drawn here
            page.wait_for_function("() => document.querySelector('canvas.main-canvas').dataset.epipolarCurves === '1'")
        page.mouse.click(*page.evaluate(SCREEN_OF, truth(v, 0).tolist()))
    moved = page.evaluate(CLICK, [0, 0])
    assert moved["from"] == "triangulated"
    assert np.hypot(*(np.array([moved["x"], moved["y"]]) - truth(0, 0))) < 1.0  # was 3 px off
    page.keyboard.press("Control+z")  # one step: the click and the re-projection it caused
    back = page.evaluate(CLICK, [0, 0])
    assert back["from"] == "mvnet" and page.evaluate(CLICK, [2, 0]) is None
    page.keyboard.press("Control+Shift+z")
    assert page.evaluate(CLICK, [0, 0])["from"] == "triangulated"

    submit_as_is(page)
    page.wait_for_function(f"() => document.body.dataset.sample !== '{task['sample_id']}' || "
                           "document.body.dataset.ready === 'annotate-empty'", timeout=30_000)
    with stack.session_factory()() as session:
        rows = session.execute(text("SELECT view_id, keypoint, from_proposal FROM clicks WHERE sample_id = :s AND "
                                    "visibility != 'not_annotated'"), {"s": task["sample_id"]}).all()
    flags = {(view, k): bool(f) for view, k, f in rows}
    first, second, third = (v["id"] for v in task["views"][:3])
    assert flags == {(first, 0): True, (first, 4): False, (first, 12): True, (first, 16): True, (first, 20): True,
                     (second, 0): False, (third, 0): False}, flags
    assert not t.errors, t.errors
