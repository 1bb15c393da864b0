"""Every key of the annotate page's Keys panel, pressed in a real browser: O and N change the point just
placed (not the next one the selection moved to) or the one picked by a digit; keys work while a button has
the focus and Esc gives them back to the view."""

from __future__ import annotations

import pytest

from tests.browser.conftest import (
    IMAGE_OF,
    SAMPLE,
    SCALE,
    SCREEN_OF,
    STATUS,
    VIEWPORT,
    WHOLE_SCALE,
    sign_in,
    submit_as_is,
)

pytestmark = [pytest.mark.browser, pytest.mark.slow]

STATE = """() => { const d = document.body.dataset; const c = document.querySelector('canvas.main-canvas');
  return {view: Number(d.viewIndex), keypoint: Number(d.keypoint), mode: d.mode, tool: d.tool, radius: Number(d.radius),
  showMask: d.showMask === 'yes', scale: Number(c.dataset.scale), help: document.querySelector('.side .help').open,
  focus: document.activeElement === c ? 'canvas' : document.activeElement.tagName}; }"""
# How many keypoints are set (placed or marked not annotated) in the view on screen (its thumbnail's data-k*).
SET_HERE = r"""() => { const t = document.querySelectorAll('.thumbs .thumb')[Number(document.body.dataset.viewIndex)];
  return Object.keys(t.dataset).filter((k) => /^k\d+$/.test(k) && t.dataset[k] !== 'unset').length; }"""


def click_at(page, u: float, v: float) -> None:
    page.evaluate("() => { const p = window.__handloop.page; p.fitView({whole: true}); p.renderNow(true); }")
    page.mouse.click(*page.evaluate(SCREEN_OF, [u, v]))


def test_every_listed_key_does_what_the_panel_says(live_stack, tab):
    stack = live_stack(worker=False)
    t = tab()
    user = stack.users["annotator"]
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    page = t.page
    state = lambda: page.evaluate(STATE)  # noqa: E731
    status = lambda v, k: page.evaluate(STATUS, [v, k])  # noqa: E731
    # The sequence named as the exports name it (seq000), not "sequence 1".
    assert page.inner_text(".sample-head .muted").startswith("seq000 · frame "), page.inner_text(".sample-head")
    listed = page.eval_on_selector_all(".help td kbd", "els => els.map((e) => e.textContent)")
    for key in ("1 … 6", "O", "N", "A / Enter", "Tab / Shift+Tab", "Del / Backspace", "M", "P", "[ ] / wheel",
                "+ / - / 0", "H", "Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y", "Ctrl+Enter", "Esc", "?"):
        assert key in listed, (key, listed)

    # O right after a click: the wrist just placed turns occluded, not the thumb the selection moved to.
    page.keyboard.press("1")
    click_at(page, 30.0, 40.0)
    assert state()["keypoint"] == 4
    page.keyboard.press("o")
    assert (status(0, 0), status(0, 4)) == ("occluded", "unset")
    assert "O/N: wrist (just placed)" in page.inner_text(".hud")
    # N right after a click: the thumb just placed, and the selection stays on the index finger.
    click_at(page, 50.0, 40.0)
    page.keyboard.press("n")
    assert (status(0, 4), state()["keypoint"]) == ("not_annotated", 8)
    # A digit picks: O then applies to the picked keypoint.
    page.keyboard.press("1")
    page.keyboard.press("o")
    assert status(0, 0) == "visible"
    # Del clears the picked keypoint; Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y undo and redo it.
    page.keyboard.press("Delete")
    assert status(0, 0) == "unset"
    page.keyboard.press("Control+z")
    assert status(0, 0) == "visible"
    page.keyboard.press("Control+Shift+z")
    assert status(0, 0) == "unset"
    page.keyboard.press("Control+z")
    page.keyboard.press("Control+y")
    assert status(0, 0) == "unset"
    page.keyboard.press("Control+z")

    # Tab / Shift+Tab change views; a wrist in two views proposes one in the third: A accepts it, Enter all.
    page.keyboard.press("Tab")
    assert state()["view"] == 1
    page.keyboard.press("1")
    click_at(page, 32.0, 42.0)
    page.keyboard.press("Tab")
    assert state()["view"] == 2
    page.keyboard.press("Shift+Tab")
    assert state()["view"] == 1
    page.keyboard.press("Tab")
    page.keyboard.press("1")
    assert page.inner_text(".kp-list .kp-row >> nth=0 >> .kp-status").startswith("proposal ")  # the wrist's
    page.keyboard.press("a")
    assert status(2, 0) == "visible"
    page.keyboard.press("Tab")
    page.keyboard.press("Enter")
    assert status(3, 0) == "visible"

    # Mask keys: M on and off, B brush, E eraser, P points, [ ] the brush, H the mask.
    page.keyboard.press("m")
    assert state()["mode"] == "mask"
    page.keyboard.press("m")
    assert state()["mode"] == "points"
    page.keyboard.press("e")
    assert (state()["mode"], state()["tool"]) == ("mask", "eraser")
    page.keyboard.press("b")
    assert state()["tool"] == "brush"
    radius = state()["radius"]
    page.keyboard.press("]")
    assert state()["radius"] > radius
    page.keyboard.press("[")
    page.keyboard.press("[")
    assert state()["radius"] < radius
    page.keyboard.press("p")
    assert state()["mode"] == "points"
    page.keyboard.press("h")
    assert state()["showMask"] is False
    page.keyboard.press("h")
    # Zoom: + and - at the centre, 0 fits again.
    fitted = state()["scale"]
    page.keyboard.press("+")
    assert state()["scale"] > fitted
    page.keyboard.press("-")
    page.keyboard.press("-")
    assert state()["scale"] < fitted
    page.keyboard.press("0")
    assert abs(state()["scale"] - fitted) < 1e-9
    # ? opens the list, Esc closes it.
    page.keyboard.press("?")
    assert state()["help"] is True

    # With a button focused the keys still act on the view; Esc hands the focus back to the view.
    page.click(".thumb >> nth=3")  # the view on screen: the thumbnail button keeps the focus
    assert state()["focus"] == "BUTTON"
    page.keyboard.press("3")
    assert state()["keypoint"] == 8
    page.keyboard.press("Escape")
    assert state()["focus"] == "canvas" and state()["help"] is False

    sample = page.evaluate(SAMPLE)
    submit_as_is(page)
    page.wait_for_function(f"() => document.body.dataset.sample !== '{sample}' || "
                           "document.body.dataset.ready === 'annotate-empty'", timeout=30_000)
    assert not t.errors, t.errors


# The Keys panel, row by row (a row added to the panel without a test here fails the next test).
PANEL = ["1 … 6", "click", "drag", "A / Enter", "O", "N", "Del / Backspace", "Tab / Shift+Tab", "M", "[ ] / wheel",
         "P", "wheel, right-drag", "+ / - / 0", "H", "Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y", "X", "Ctrl+Enter", "Esc", "?"]
CLICK = "([v, k]) => { const p = window.__handloop.page; return p.annotation.get(p.views[v].id, k); }"


def test_the_pointer_rows_of_the_panel_and_the_keys_they_combine_with(live_stack, tab):
    # The rows the test above does not press: Backspace, a drag (and Esc ending it unapplied), the wheel
    # (zoom at the cursor; brush size in mask mode, Ctrl+wheel zooms there), right-drag and Space+drag pan,
    # 0 twice (the hand, then the whole image).
    stack = live_stack(worker=False)
    t = tab()
    user = stack.users["annotator"]
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    page = t.page
    listed = page.eval_on_selector_all(".help td kbd", "els => els.map((e) => e.textContent)")
    assert listed == PANEL, listed
    status = lambda v, k: page.evaluate(STATUS, [v, k])  # noqa: E731
    viewport = lambda: page.evaluate(VIEWPORT)  # noqa: E731

    # Backspace clears the picked keypoint, as Del does.
    page.keyboard.press("1")
    click_at(page, 30.0, 40.0)
    page.keyboard.press("1")
    page.keyboard.press("Backspace")
    assert status(0, 0) == "unset"
    # drag: a point placed, then dragged 10 image px to the right; Esc during a drag leaves it where it was.
    click_at(page, 30.0, 40.0)
    start = page.evaluate(SCREEN_OF, [30.0, 40.0])
    scale = viewport()[0]
    page.mouse.move(*start)
    page.mouse.down()
    page.mouse.move(start[0] + 10 * scale, start[1], steps=4)
    page.mouse.up()
    moved = page.evaluate(CLICK, [0, 0])
    assert abs(moved["x"] - 40.0) < 0.6 and abs(moved["y"] - 40.0) < 0.6, moved
    here = page.evaluate(SCREEN_OF, [moved["x"], moved["y"]])
    page.mouse.move(*here)
    page.mouse.down()
    page.mouse.move(here[0] + 20 * scale, here[1] + 5 * scale, steps=4)
    page.keyboard.press("Escape")
    page.mouse.up()
    assert page.evaluate(CLICK, [0, 0]) == moved

    # wheel: zoom at the cursor in points mode (the image point under it stays put).
    canvas = page.locator("canvas.main-canvas").bounding_box()
    cursor = [canvas["x"] + canvas["width"] * 0.3, canvas["y"] + canvas["height"] * 0.4]
    page.mouse.move(*cursor)
    under = page.evaluate(IMAGE_OF, [cursor[0] - canvas["x"], cursor[1] - canvas["y"]])
    before = viewport()
    page.mouse.wheel(0, -200)
    page.wait_for_function(f"() => ({SCALE})() > {before[0]}")
    after = page.evaluate(SCREEN_OF, under)
    assert abs(after[0] - cursor[0]) < 0.5 and abs(after[1] - cursor[1]) < 0.5
    # In mask mode the wheel sizes the brush and leaves the zoom; Ctrl+wheel zooms.
    page.keyboard.press("m")
    radius, zoom = page.evaluate(STATE)["radius"], viewport()
    page.mouse.wheel(0, -100)
    page.wait_for_function(f"() => Number(document.body.dataset.radius) > {radius}")
    assert viewport() == zoom
    page.keyboard.down("Control")
    page.mouse.wheel(0, 200)
    page.keyboard.up("Control")
    page.wait_for_function(f"() => ({SCALE})() < {zoom[0]}")
    page.keyboard.press("p")
    # right-drag pans, Space + drag pans (in points mode, where a left drag would place a point).
    placed = page.evaluate(SET_HERE)
    for hold in ("right", "Space"):
        before = viewport()
        page.mouse.move(*cursor)
        if hold == "Space":
            page.keyboard.down("Space")
        page.mouse.down(button="right" if hold == "right" else "left")
        page.mouse.move(cursor[0] + 40, cursor[1] + 25, steps=4)
        page.mouse.up(button="right" if hold == "right" else "left")
        if hold == "Space":
            page.keyboard.up("Space")
        after = viewport()
        assert after[0] == before[0] and abs(after[1] - before[1] - 40) < 0.5 and abs(after[2] - before[2] - 25) < 0.5
    assert page.evaluate(SET_HERE) == placed  # panning placed nothing
    # 0 fits the hand; pressed again, the whole image.
    page.keyboard.press("0")
    hand = viewport()
    page.keyboard.press("0")
    whole = viewport()
    whole_scale = page.evaluate(WHOLE_SCALE)
    assert abs(whole[0] - whole_scale) < 1e-6 and hand[0] > whole[0], (hand, whole, whole_scale)  # closer on the hand
    assert not t.errors, t.errors
