"""The review page's discard (D): offered only for a fit from predictions (a fit from annotators' clicks would lose
their work in the next round's refit); a discard leaves the sample in the pool for the next round. Real browser,
real API, real worker (it fits the sample)."""

from __future__ import annotations

import pytest
from sqlalchemy import text

from tests.browser.conftest import sign_in
from tests.browser.test_review_notes_and_keys import _one_sample_in_review

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_discard_is_offered_for_fits_from_predictions_only(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    sample = _one_sample_in_review(stack)
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    assert page.get_attribute("body", "data-sample") == str(sample)
    # A fit from clicks: no button, and the key says what to do instead; nothing is decided.
    assert page.locator("button.discard").count() == 0
    # The key and the toast it raises in one evaluation: the toast lives 3 s, which a loaded machine may outlast.
    said = page.evaluate("() => { window.dispatchEvent(new KeyboardEvent('keydown', {key: 'd'})); "
                         "return [...document.querySelectorAll('.toast')].map((e) => e.textContent).join(' | '); }")
    assert "annotators' clicks" in said, said
    assert page.get_attribute("body", "data-sample") == str(sample)
    with stack.session_factory()() as session:
        assert session.execute(text("SELECT count(*) FROM decisions")).scalar_one() == 0
        # The same fit as if it came from predictions (the worker's own path is tested in the API tests).
        session.execute(text("UPDATE fits SET inputs = '{}' WHERE id = (SELECT current_fit_id FROM samples "
                             "WHERE id = :s)"), {"s": sample})
        session.commit()
    page.reload()
    page.wait_for_selector(f"body[data-ready=review][data-sample='{sample}']", state="attached", timeout=60_000)
    assert page.locator("button.discard").is_visible()
    page.keyboard.press("d")
    page.wait_for_selector("body[data-ready=review-empty]", state="attached", timeout=60_000)
    with stack.session_factory()() as session:
        decision = session.execute(text("SELECT decision FROM decisions WHERE sample_id = :s"),
                                   {"s": sample}).scalar_one()
        state = session.execute(text("SELECT state FROM samples WHERE id = :s"), {"s": sample}).scalar_one()
    assert (decision, state) == ("discard", "fitted")
    assert not t.errors, t.errors
