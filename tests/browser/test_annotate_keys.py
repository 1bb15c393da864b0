"""Every key of the annotate page's Keys panel, pressed in a real browser: O and N change the point just
placed (not the next one the selection moved to) or the one picked by a digit; keys work while a button has
the focus and Esc gives them back to the view."""

from __future__ import annotations

import pytest

from tests.browser.conftest import sign_in

pytestmark = [pytest.mark.browser, pytest.mark.slow]

SCREEN_OF = """([u, v]) => { const p = window.__handloop.page; const r = p.canvas.getBoundingClientRect();
  const s = p.vp.toScreen(u, v); return [r.left + s[0], r.top + s[1]]; }"""
STATUS = "([v, k]) => { const p = window.__handloop.page; return p.annotation.status(p.views[v].id, k); }"
STATE = """() => { const p = window.__handloop.page; return {view: p.viewIndex, keypoint: p.keypoint, mode: p.mode,
  tool: p.tool, radius: p.radius, showMask: p.showMask, scale: p.vp.scale, help: p.side.querySelector('.help').open,
  focus: document.activeElement === p.canvas ? 'canvas' : document.activeElement.tagName}; }"""


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
    assert page.evaluate("() => { const p = window.__handloop.page; return p.proposals.get(p.view.id).has(0); }")
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

    sample = page.evaluate("() => window.__handloop.page.task.sample_id")
    page.keyboard.press("Control+Enter")
    page.wait_for_function(f"() => document.body.dataset.sample !== '{sample}' || "
                           "document.body.dataset.ready === 'annotate-empty'", timeout=30_000)
    assert not t.errors, t.errors
