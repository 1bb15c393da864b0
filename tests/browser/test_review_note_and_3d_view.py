"""Issue 38 on the review page, acted out in a real browser against a live stack (real worker: it fits).

Item 8: a digit pressed while the reviewer writes a note of their own is typed into it (it used to replace the
whole note with a common reason), and the note's length limit is shown before the server would refuse it.
Item 11: the 3D view can be laid over the image grid (F or its button) and given the screen, viser's
"Software WebGL rendering detected" notification no longer covers it, and the Keys list opens in sight."""

from __future__ import annotations

import pytest
from sqlalchemy import text

from tests.browser.conftest import open_3d_view, sign_in
from tests.browser.test_review_notes_and_keys import _one_sample_in_review

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_digits_are_typed_into_a_note_of_ones_own_and_the_limit_is_shown(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    sample = _one_sample_in_review(stack)
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    page.keyboard.press("n")
    assert page.evaluate("() => document.activeElement.classList.contains('reason-input')")
    page.keyboard.type("tips of fingers 1 and 2 swapped in view 3")
    note = page.input_value(".reason-input")
    assert note == "tips of fingers 1 and 2 swapped in view 3", note  # on main: "the wrist is off" etc.
    assert page.inner_text(".reason-count") == f"{len(note)} / 2000 characters"
    assert page.get_attribute(".reason-input", "maxlength") == "2000"
    # An empty note: a digit still picks a common reason (and one picked reason can be swapped for another).
    page.fill(".reason-input", "")
    page.keyboard.press("2")
    assert page.input_value(".reason-input") == "the wrist is off"
    page.keyboard.press("3")
    assert page.input_value(".reason-input") == "the silhouette misses fingers"
    page.keyboard.type(" 4")  # words of one's own after it: the digit is typed
    assert page.input_value(".reason-input") == "the silhouette misses fingers 4"
    page.fill(".reason-input", "x" * 2100)  # the box stops at the server's limit
    assert len(page.input_value(".reason-input")) == 2000
    assert page.inner_text(".reason-count") == "2000 / 2000 characters"
    page.fill(".reason-input", "view 3: tips 1 and 2 swapped")
    page.keyboard.press("Enter")
    page.wait_for_function(f"() => document.body.dataset.ready === 'review-empty' || "
                           f"document.body.dataset.sample !== '{sample}'", timeout=30_000)
    with stack.session_factory()() as session:
        stored = session.execute(text("SELECT decision, reason FROM decisions WHERE sample_id = :s"),
                                 {"s": sample}).one()
    assert tuple(stored) == ("annotate", "view 3: tips 1 and 2 swapped")
    assert not t.errors, t.errors


def test_the_3d_view_goes_large_and_full_screen_without_viser_notice_and_keys_are_in_sight(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    _one_sample_in_review(stack)
    t = tab(1600, 900)
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    open_3d_view(page, loaded=True)
    side = page.locator("iframe.viewer-frame").bounding_box()
    assert side["height"] >= 240, side  # on main: 260 px tall at most beside a 355 px wide panel
    # The Keys list sits above the 3D view: opened with ?, all of it is inside the window.
    page.keyboard.press("?")
    help_box = page.locator(".review-side .help").bounding_box()
    assert help_box["y"] + help_box["height"] <= 900, help_box
    page.keyboard.press("?")
    # F lays the 3D view over the image grid, the same iframe (no reload: the scene and camera stay).
    page.evaluate("() => { window.__frame = document.querySelector('iframe.viewer-frame'); }")
    page.keyboard.press("f")
    assert page.get_attribute("body", "data-viewer3d") == "large"
    large = page.locator("iframe.viewer-frame").bounding_box()
    assert large["width"] >= 1000 and large["height"] >= 700, large
    assert page.evaluate("() => window.__frame === document.querySelector('iframe.viewer-frame')")
    page.keyboard.press("f")
    assert page.get_attribute("body", "data-viewer3d") == "side"
    page.click(".viewer-size")
    assert page.get_attribute("body", "data-viewer3d") == "large"
    page.keyboard.press("Escape")
    assert page.get_attribute("body", "data-viewer3d") == "side"
    page.click(".viewer-fullscreen")
    page.wait_for_function("() => document.fullscreenElement && document.fullscreenElement.tagName === 'IFRAME'",
                           timeout=10_000)
    page.evaluate("() => document.exitFullscreen()")
    # viser's own software-rendering notification is hidden once it shows (headless Chromium renders WebGL in
    # software); the page says it in one short line instead.
    page.wait_for_function("() => document.querySelector('iframe.viewer-frame').dataset.softwareNotice === 'hidden'",
                           timeout=30_000)
    shown = page.evaluate("""() => {
      const doc = document.querySelector('iframe.viewer-frame').contentDocument;
      return [...doc.querySelectorAll('body *')].filter((e) => e.children.length === 0
        && /software\\s+(webgl\\s+)?rendering/i.test(e.textContent) && e.getClientRects().length > 0)
        .map((e) => e.textContent);
    }""")
    assert shown == [], shown
    assert "software WebGL" in page.inner_text(".software-note")
    t.shot("review-3d-large")
    assert not t.errors, t.errors
