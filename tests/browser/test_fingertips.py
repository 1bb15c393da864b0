"""Fingertips easy to hit, in a real browser: a view opens cropped to the hand and keeps its zoom per view
(and sample); a magnifier follows the cursor in points mode; the mask shows as an outline only in points
mode (the skin under it as it is), filled in mask mode."""

from __future__ import annotations

import pytest

from tests.browser.conftest import (
    IMAGE_OF,
    SAMPLE,
    SCALE,
    SCREEN_OF,
    TASK,
    VIEWPORT,
    WHOLE_SCALE,
    sign_in,
    submit_as_is,
    wait_for_every_view,
)
from tests.support.annotate import ground_truth_of

pytestmark = [pytest.mark.browser, pytest.mark.slow]

# The mask pixel nearest the view's centre on screen whose 7x7 neighbourhood is all inside (no outline).
INTERIOR = """() => { const p = window.__handloop.page; const m = p.view.mask; const w = m.width;
  const r = p.canvas.getBoundingClientRect(); const [cu, cv] = p.vp.toImage(r.width / 2, r.height / 2);
  let best = null, bestD = Infinity;
  for (let y = 3; y < m.height - 3; y++) for (let x = 3; x < w - 3; x++) { let all = true;
    for (let dy = -3; dy <= 3 && all; dy++) for (let dx = -3; dx <= 3 && all; dx++) {
      all = m.bits[(y + dy) * w + x + dx] === 1; }
    const d = Math.hypot(x - cu, y - cv); if (all && d < bestD) { best = [x, y]; bestD = d; } }
  return best; }"""
PIXEL = """([x, y]) => { const p = window.__handloop.page; p.renderNow(true); const c = p.canvas;
  const r = c.getBoundingClientRect(); const dpr = c.width / r.width;
  return Array.from(c.getContext('2d').getImageData(Math.round(x * dpr), Math.round(y * dpr), 1, 1).data); }"""


def test_views_open_on_the_hand_keep_their_zoom_and_show_a_magnifier_and_an_outline(live_stack, tab):
    stack = live_stack(worker=False)
    t = tab()
    user = stack.users["annotator"]
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    page = t.page
    wait_for_every_view(page)  # the third view's mask is read below
    task = page.evaluate(TASK)
    gt = ground_truth_of(stack, task)
    names = list(gt.camera_names)
    canvas = page.locator("canvas.main-canvas").bounding_box()

    # Wrist and tips in two views; the third opens on the hand they triangulate to, larger than the whole image.
    for v in (0, 1):
        page.click(f".thumb >> nth={v}")
        c = names.index(task["views"][v]["camera"])
        for i, k in enumerate((0, 4, 8, 12, 16, 20)):
            page.keyboard.press(str(i + 1))
            page.mouse.click(*page.evaluate(SCREEN_OF, gt.keypoints_2d[c, k].tolist()))
    page.click(".thumb >> nth=2")
    scale = page.evaluate(SCALE)
    assert scale > 1.1 * page.evaluate(WHOLE_SCALE), (scale, page.evaluate(WHOLE_SCALE))
    proposed = page.evaluate("() => { const p = window.__handloop.page;"
                             " return [...p.proposals.get(p.view.id).values()].map((q) => [q.x, q.y]); }")
    assert len(proposed) >= 4
    for uv in proposed:
        x, y = page.evaluate(SCREEN_OF, uv)
        assert canvas["x"] <= x <= canvas["x"] + canvas["width"], (uv, x)
        assert canvas["y"] <= y <= canvas["y"] + canvas["height"], (uv, y)

    # Each view keeps its zoom: zoomed in view 3, away to view 4 and back.
    page.keyboard.press("+")
    zoomed = page.evaluate(f"() => ({VIEWPORT})().slice(0, 2)")
    page.keyboard.press("Tab")
    page.keyboard.press("Shift+Tab")
    assert page.evaluate(f"() => ({VIEWPORT})().slice(0, 2)") == zoomed
    page.keyboard.press("0")

    # The outline only in points mode: inside the mask the image is as with the mask hidden; filled in mask mode.
    inside = page.evaluate(INTERIOR)
    assert inside is not None
    sx, sy = page.evaluate(SCREEN_OF, inside)
    at = [sx - canvas["x"], sy - canvas["y"]]
    page.mouse.move(canvas["x"] + 2, canvas["y"] + canvas["height"] - 2)  # the magnifier away from the point
    page.mouse.move(canvas["x"] - 20, canvas["y"] - 20)
    points_mode = page.evaluate(PIXEL, at)
    page.keyboard.press("h")
    hidden = page.evaluate(PIXEL, at)
    page.keyboard.press("h")
    page.keyboard.press("m")
    mask_mode = page.evaluate(PIXEL, at)
    page.keyboard.press("m")
    assert points_mode == hidden and mask_mode != hidden, (points_mode, hidden, mask_mode)

    # The magnifier: centred on the image point under the cursor, drawn beside it.
    cursor = [canvas["x"] + canvas["width"] / 2, canvas["y"] + canvas["height"] / 2]
    page.mouse.move(*cursor)
    page.wait_for_function("() => window.__handloop.page.loupe && !window.__handloop.page.frame")
    loupe = page.evaluate("() => window.__handloop.page.loupe")
    u, v = page.evaluate(IMAGE_OF,
                         [cursor[0] - canvas["x"], cursor[1] - canvas["y"]])
    assert abs(loupe["u"] - u) < 1e-6 and abs(loupe["v"] - v) < 1e-6 and loupe["zoom"] >= 1.5
    assert abs(loupe["cx"] - (cursor[0] - canvas["x"])) == 80
    t.shot("annotate-magnifier-outline")

    # Per sample: the next sample's view 3 opens on its own hand, not with this sample's zoom of view 3.
    page.keyboard.press("+")
    zoomed = page.evaluate(f"() => ({VIEWPORT})().slice(0, 2)")
    sample = page.evaluate(SAMPLE)
    submit_as_is(page)
    page.wait_for_function(f"() => document.body.dataset.sample !== '{sample}' && "
                           "document.body.dataset.ready === 'annotate'", timeout=30_000)
    page.click(".thumb >> nth=2")
    assert page.evaluate(f"() => ({VIEWPORT})().slice(0, 2)") != zoomed
    assert not t.errors, t.errors
