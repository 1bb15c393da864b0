"""Issue 38, item 11, acted out in a real browser against a live stack: one sign-in serves every tab of the
browser (a new tab asked for a fresh sign-in) and a sign-out or sign-in in one tab reaches the others; the
guidelines an admin writes (text and an image) open on the annotate and review pages; a light theme and a
larger-target mode, kept after a reload; the magnifier goes when the pointer leaves the view, also at the end
of a drag carried past the canvas's edge."""

from __future__ import annotations

import io

import pytest
from PIL import Image

from tests.browser.conftest import sign_in

pytestmark = [pytest.mark.browser, pytest.mark.slow]

GUIDE = "Occluded fingertips: place them where you judge they are and press O.\n\nNo hand in a view: say so."


def _png() -> bytes:
    out = io.BytesIO()
    Image.new("RGB", (40, 30), (30, 160, 220)).save(out, "PNG")
    return out.getvalue()


def test_tabs_share_a_sign_in_guidelines_show_and_the_look_changes(live_stack, tab):
    stack = live_stack(worker=False)
    t = tab(1600, 900)
    first = t.page
    admin = stack.users["admin"]
    sign_in(t, stack.base_url, admin.email, admin.password, "admin")
    # The admin writes the guidelines: text, then an image with a caption.
    first.wait_for_selector("#guidelines-editor[data-revision='0']", state="attached", timeout=30_000)
    first.fill("#guidelines-editor textarea", GUIDE)
    first.click("#guidelines-editor .save-guidelines")
    first.wait_for_selector("#guidelines-editor[data-revision='1']", state="attached", timeout=10_000)
    first.set_input_files("#guidelines-editor input[type=file]",
                          files=[{"name": "tips.png", "mimeType": "image/png", "buffer": _png()}])
    first.fill("#guidelines-editor input[name=guidelines-caption]", "where an occluded tip goes")
    first.click("#guidelines-editor .guidelines-upload button[type=submit]")
    first.wait_for_selector("#guidelines-editor[data-revision='2'] .guideline-figure img", state="attached",
                            timeout=10_000)

    # A second tab of the same browser is signed in already (on main: the login form again).
    second = first.context.new_page()
    second.on("pageerror", lambda e: t.errors.append(str(e)))
    second.goto(stack.base_url + "/")
    second.wait_for_selector("body[data-ready=admin]", state="attached", timeout=30_000)
    # Signing out in one tab signs the other out; signing in there brings the first along.
    second.click("#nav button:has-text('Sign out')")
    second.wait_for_selector("body[data-ready=login]", state="attached", timeout=10_000)
    first.wait_for_selector("body[data-ready=login]", state="attached", timeout=10_000)
    annotator = stack.users["annotator"]
    second.fill("input[name=email]", annotator.email)
    second.fill("input[name=password]", annotator.password)
    second.click("button[type=submit]")
    second.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)
    first.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)
    second.close()

    # The guidelines open by themselves once (a revision this person has not seen), with the image.
    panel = first.locator(".guidelines-panel")
    panel.wait_for(state="visible", timeout=10_000)
    assert "press O" in panel.inner_text() and "No hand in a view" in panel.inner_text()
    first.wait_for_function("() => { const i = document.querySelector('.guidelines-panel img');"
                            " return i && i.complete && i.naturalWidth === 40; }", timeout=10_000)
    assert "where an occluded tip goes" in panel.inner_text()
    first.click(".guidelines-panel .close")
    assert panel.is_hidden()
    first.reload()
    first.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)
    assert first.locator(".guidelines-panel").is_hidden()  # seen: behind the button now
    first.click(".guidelines-button")
    assert first.locator(".guidelines-panel").is_visible()
    first.click(".guidelines-panel .close")

    # The magnifier: shown over the view, gone once the pointer is out, also after a pan dragged past the edge.
    box = first.locator("canvas.main-canvas").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    first.mouse.move(cx, cy)
    assert first.get_attribute("canvas.main-canvas", "data-hover") == "yes"
    first.mouse.down(button="middle")
    first.mouse.move(box["x"] + box["width"] + 60, cy, steps=4)  # onto the side panel, still dragging
    first.mouse.up(button="middle")
    assert first.get_attribute("canvas.main-canvas", "data-hover") == "no"

    # The Keys list opens in sight (it sits at the foot of the side panel and opened below the fold).
    first.keyboard.press("?")
    first.wait_for_function("() => document.querySelector('.side .help').open")
    # In sight: all of it, or (taller than the window) from its top, in the upper half of the window, on.
    first.wait_for_function("() => { const b = document.querySelector('.side .help').getBoundingClientRect();"
                            " return b.top >= 0 && (b.bottom <= window.innerHeight"
                            " || b.top <= window.innerHeight / 2); }", timeout=5_000)
    first.keyboard.press("?")

    # The light theme and the larger targets, kept per browser.
    first.click("#nav .look-theme")
    assert first.get_attribute("html", "data-theme") == "light"
    assert first.evaluate("() => getComputedStyle(document.body).backgroundColor") == "rgb(243, 244, 246)"
    first.click("#nav .look-targets")
    assert first.get_attribute("html", "data-targets") == "large"
    assert first.evaluate("() => getComputedStyle(document.body).fontSize") == "17px"
    submit = first.locator(".side button").first.bounding_box()
    assert submit["height"] >= 40, submit
    first.reload()
    first.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)
    look = (first.get_attribute("html", "data-theme"), first.get_attribute("html", "data-targets"))
    assert look == ("light", "large"), look
    t.shot("annotate-light-large")

    # The review page shows the guidelines too (open by themselves: the reviewer has not closed them yet).
    r = tab(1600, 900)
    reviewer = stack.users["reviewer"]
    sign_in(r, stack.base_url, reviewer.email, reviewer.password, "review-empty")
    r.page.locator(".guidelines-panel").wait_for(state="visible", timeout=10_000)
    assert "press O" in r.page.inner_text(".guidelines-panel")
    assert not t.errors, t.errors
    assert not r.errors, r.errors
