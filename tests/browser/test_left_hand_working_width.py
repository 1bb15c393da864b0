"""Issue 18 in a real browser: a left-hand capture's annotate page says "left hand", and a project with a
working width narrower than its views gets the working-width images, drawn over the full-resolution view,
so a click lands in full-resolution pixels where the keypoint is."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import update

from tests.browser.conftest import SCALE, SCREEN_OF, TASK, sign_in, wait_for_every_view
from tests.support.annotate import ground_truth_of

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CANVAS_RGB = """(points) => { const p = window.__handloop.page; const ctx = p.canvas.getContext('2d');
  const dpr = window.devicePixelRatio || 1;
  return points.map(([u, v]) => { const s = p.vp.toScreen(u, v);
    return Array.from(ctx.getImageData(Math.round(s[0] * dpr), Math.round(s[1] * dpr), 1, 1).data).slice(0, 3); }); }"""
WORKING_WIDTH = 80  # the tiny capture's views are 160 px wide


def test_a_left_hand_at_a_working_width_is_named_and_clicked_in_full_resolution_pixels(live_stack, tab):
    from backend.models.capture import Project

    stack = live_stack(worker=False, side="left")
    with stack.session_factory().begin() as session:
        session.execute(update(Project).values(working_width_px=WORKING_WIDTH))
    t = tab()
    user = stack.users["annotator"]
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    page = t.page
    assert page.inner_text(".hand-side") == "left hand"
    assert page.get_attribute(".hand-side", "data-side") == "left"
    wait_for_every_view(page)
    sizes = page.evaluate("() => window.__handloop.page.views.map((v) => [v.width, v.image.width])")
    assert all(view == 160 and image == WORKING_WIDTH for view, image in sizes), sizes

    task = page.evaluate(TASK)
    gt = ground_truth_of(stack, task)
    c = list(gt.camera_names).index(task["views"][0]["camera"])
    target = np.asarray(gt.keypoints_2d[c, 0], float)
    page.evaluate("() => { const p = window.__handloop.page; p.fitView({whole: true}); p.renderNow(true); }")
    page.keyboard.press("1")
    page.mouse.click(*page.evaluate(SCREEN_OF, target.tolist()))
    clicked = page.evaluate("""(id) => window.__handloop.page.annotation.toClicks()
        .find((c) => c.view_id === id && c.keypoint === 0)""", task["views"][0]["id"])
    # Screen pixels are coarser than image pixels at this zoom: within one screen pixel's worth.
    scale = page.evaluate(SCALE)
    assert np.hypot(clicked["x"] - target[0], clicked["y"] - target[1]) <= 1.0 / scale + 0.5, (clicked, target)
    # The copy is drawn over the whole view (not its left half at 1:1): the canvas shows the original's
    # colours in the right half too.
    import cv2

    from workers.capture import read_capture

    capture = read_capture(stack.capture_dir, check_images=False)
    frame = capture.sequences[0].frames[task["frame_index"]]
    original = cv2.cvtColor(cv2.imread(str(frame.image_paths[task["views"][0]["camera"]])), cv2.COLOR_BGR2RGB)
    points = [[u, v] for u in (96.0, 120.0, 144.0) for v in (16.0, 64.0, original.shape[0] - 16.0)]
    drawn = np.asarray(page.evaluate(CANVAS_RGB, points), float)
    expected = np.asarray([original[int(v), int(u)] for u, v in points], float)
    assert np.median(np.abs(drawn - expected).max(axis=1)) < 30, (drawn, expected)
    t.shot("left-hand-working-width")
    assert not t.errors, t.errors
