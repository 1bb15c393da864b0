"""The review page: a reviewer's note in progress survives a reload; digits pick a common reason even while
the text box has focus (never typed into it); after a click in the 3D view (its iframe keeps the focus)
every key still works and Esc hands the focus back. Real browser, real API, real worker (it fits)."""

from __future__ import annotations

import pytest
from sqlalchemy import text

from tests.browser.conftest import open_3d_view, sign_in
from tests.support.annotate import clicks_body, queue_for_annotation, wait_until

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _one_sample_in_review(stack) -> int:
    queue_for_annotation(stack, 1)
    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()
        response = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=clicks_body(stack, task))
        assert response.status_code == 201, response.text
    with stack.client("admin") as http:
        wait_until(lambda: http.get("/api/admin/rounds/statistics").json()["samples_by_state"].get("in_review"),
                   300, "the fit of the annotated sample", stack)
    return task["sample_id"]


def test_a_reviewers_note_survives_a_reload_and_digits_pick_reasons(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    sample = _one_sample_in_review(stack)
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    assert page.get_attribute("body", "data-sample") == str(sample)
    assert "seq000 · frame " in page.inner_text(".review-side"), page.inner_text(".review-side")  # as exports say
    # The review clock waits for the reviewer's first act (the time before it is not verification).
    assert page.inner_text(".review-side .clock") == "time starts when you act"
    assert "no MVNet prediction exists for this sample" in page.inner_text(".mvnet-note")  # a fit from clicks
    assert page.evaluate("() => window.__handloop.page.spentSeconds()") == 0
    page.keyboard.press("r")
    assert page.evaluate("() => document.body.dataset.clock") == "runs"
    assert page.evaluate("() => document.activeElement.classList.contains('reason-input')")  # typing goes there
    page.keyboard.press("2")
    reason = page.input_value(".reason-input")
    assert reason == "wrong global pose (flipped or mirrored)", reason  # the common reason, not "2"
    page.keyboard.type(", index and thumb swapped")
    page.wait_for_function("() => document.body.dataset.draftState === 'saved'", timeout=30_000)
    page.reload()
    page.wait_for_selector("body[data-ready=review]", state="attached", timeout=60_000)
    assert page.input_value(".reason-input") == reason + ", index and thumb swapped"
    page.keyboard.press("Enter")
    page.wait_for_function(f"() => document.body.dataset.ready === 'review-empty' || "
                           f"document.body.dataset.sample !== '{sample}'", timeout=30_000)
    with stack.session_factory()() as session:
        stored = session.execute(text("SELECT decision, reason FROM decisions WHERE sample_id = :s"),
                                 {"s": sample}).one()
        drafts = session.execute(text("SELECT count(*) FROM drafts")).scalar_one()
    assert tuple(stored) == ("reject", reason + ", index and thumb swapped") and drafts == 0
    assert not t.errors, t.errors


def test_keys_work_after_a_click_in_the_3d_view_and_esc_returns_the_focus(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    _one_sample_in_review(stack)
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    open_3d_view(page, loaded=True)
    box = page.locator("iframe.viewer-frame").bounding_box()
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)  # the 3D view takes the focus
    assert page.evaluate("() => document.activeElement.tagName") == "IFRAME"
    before = page.evaluate("() => document.body.dataset.layers.split(' ').includes('keypoints')")
    page.keyboard.press("k")
    assert page.evaluate("() => document.body.dataset.layers.split(' ').includes('keypoints')") is (not before)
    page.keyboard.press("2")  # enlarge view 2, from inside the iframe too
    assert page.evaluate("() => document.body.dataset.focus") == "1"
    page.keyboard.press("Escape")
    assert page.evaluate("() => document.activeElement.tagName") != "IFRAME"
    assert page.evaluate("() => document.body.dataset.focus ?? null") is None
    page.keyboard.press("z")  # and the page has the keys again
    assert page.evaluate("() => document.body.dataset.crop") == "whole"
    listed = page.eval_on_selector_all(".help td kbd", "els => els.map((e) => e.textContent)")
    assert listed == ["A", "D", "R / N", "O S W K C P", "1 … 8", "Esc", "Z", "V", "F", "?"], listed
    layers = "() => document.body.dataset.layers.split(' ')"
    for key, name in zip("oswkcp", ("outline", "silhouette", "wireframe", "keypoints", "clicks", "mvnet"), strict=True):
        before = name in page.evaluate(layers)
        page.keyboard.press(key)
        assert (name in page.evaluate(layers)) is (not before), key
    page.keyboard.press("n")
    assert page.evaluate("() => document.body.dataset.reason") == "annotate"
    page.keyboard.press("1")
    assert page.input_value(".reason-input") == "a fingertip is on the wrong finger"
    page.keyboard.press("Escape")
    assert page.evaluate("() => document.body.dataset.reason ?? null") is None
    assert page.evaluate("() => document.activeElement.tagName") == "BODY"
    page.keyboard.press("?")
    assert page.evaluate("() => document.querySelector('.review-side .help').open") is True
    shown = page.evaluate("() => document.body.dataset.show3d === 'yes'")
    page.keyboard.press("v")
    assert page.evaluate("() => document.body.dataset.show3d === 'yes'") is (not shown)
    assert not t.errors, t.errors
