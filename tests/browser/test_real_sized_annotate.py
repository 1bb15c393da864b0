"""Issue 18 in a real browser: the annotate page on 2048 px views (a capture with a 640 px working width).
The page loads the working-width copies drawn over the full-resolution views; the annotator zooms in with
the wheel and pans with a right-drag, then clicks a keypoint: the click is stored in full-resolution pixels
where the keypoint is, to within a screen pixel's worth."""

from __future__ import annotations

import numpy as np
import pytest

from tests.browser.conftest import SCALE, SCREEN_OF, TASK, VIEWPORT, sign_in, wait_for_every_view
from tests.support.annotate import ground_truth_of
from tests.support.live_stack import make_live_stack
from tests.support.real_sized import FULL_WIDTH, upscaled_capture

pytestmark = [pytest.mark.browser, pytest.mark.slow]

WORKING_WIDTH = 640


@pytest.fixture
def big_stack(tmp_path, capture_cache):
    from tests.support.live_stack import tiny_capture

    small = tiny_capture(capture_cache, frames=2, width=256)
    capture = upscaled_capture(small, capture_cache / f"{small.name}-{FULL_WIDTH}px-w{WORKING_WIDTH}",
                               working_width_px=WORKING_WIDTH)
    stack = make_live_stack(tmp_path / "data", capture, worker=False)
    yield stack
    stack.stop()


def test_zoom_pan_and_click_on_a_2048_px_view(big_stack, tab):
    stack = big_stack
    t = tab()
    user = stack.users["annotator"]
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    page = t.page
    wait_for_every_view(page)
    sizes = page.evaluate("() => window.__handloop.page.views.map((v) => [v.width, v.image.width])")
    assert sizes and all(view == FULL_WIDTH and image == WORKING_WIDTH for view, image in sizes), sizes
    task = page.evaluate(TASK)
    gt = ground_truth_of(stack, task)
    c = list(gt.camera_names).index(task["views"][0]["camera"])
    k = next(k for k in (0, 4, 8, 12, 16, 20) if gt.visibility[c, k])
    target = np.asarray(gt.keypoints_2d[c, k], float)  # full-resolution pixels of the 2048 px view

    page.evaluate("() => { const p = window.__handloop.page; p.fitView({whole: true}); p.renderNow(true); }")
    fitted = page.evaluate(VIEWPORT)
    box = page.locator("canvas.main-canvas").bounding_box()
    centre = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.move(*centre)
    for _ in range(4):  # zoom in with the wheel
        page.mouse.wheel(0, -300)
    page.wait_for_function(f"() => ({SCALE})() > {fitted[0] * 2.5}")
    zoomed = page.evaluate(VIEWPORT)
    # pan with a right-drag so the keypoint comes to the middle of the canvas
    start = page.evaluate(SCREEN_OF, target.tolist())
    page.mouse.move(*centre)
    page.mouse.down(button="right")
    page.mouse.move(centre[0] + (centre[0] - start[0]) / 2, centre[1] + (centre[1] - start[1]) / 2, steps=4)
    page.mouse.move(2 * centre[0] - start[0], 2 * centre[1] - start[1], steps=4)
    page.mouse.up(button="right")
    panned = page.evaluate(VIEWPORT)
    assert panned[0] == zoomed[0] and (panned[1], panned[2]) != (zoomed[1], zoomed[2])
    at = page.evaluate(SCREEN_OF, target.tolist())
    assert abs(at[0] - centre[0]) < 3 and abs(at[1] - centre[1]) < 3, (at, centre)  # the pan moved the image

    page.keyboard.press(str(1 + (0, 4, 8, 12, 16, 20).index(k)))
    page.mouse.click(*at)
    clicked = page.evaluate("""([id, k]) => window.__handloop.page.annotation.toClicks()
        .find((c) => c.view_id === id && c.keypoint === k)""", [task["views"][0]["id"], k])
    assert clicked is not None and clicked["visibility"] == "visible", clicked
    scale = panned[0]
    assert np.hypot(clicked["x"] - target[0], clicked["y"] - target[1]) <= 1.0 / scale + 0.5, (clicked, target, scale)
    t.shot("annotate-2048px-zoomed")
    assert not t.errors, t.errors
