"""Issue 38 item 6: the review page's activity log of a decision with a picked reason was refused (422: the page
marks "reason", which the schema did not take), so the dashboard counted fewer verifications than were made.
Real browser, real API, real worker (it fits the annotated sample)."""

from __future__ import annotations

import pytest

from tests.browser.conftest import sign_in
from tests.browser.test_review_notes_and_keys import _one_sample_in_review

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_a_decision_with_a_picked_reason_is_logged_and_counted(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    sample = _one_sample_in_review(stack)
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    assert page.get_attribute("body", "data-sample") == str(sample)
    page.keyboard.press("r")
    page.keyboard.press("2")  # a common reason, picked: the log marks it
    with page.expect_response(lambda r: r.url.endswith("/api/activity") and r.request.method == "POST") as logged:
        page.keyboard.press("Enter")
    assert logged.value.status == 201, logged.value.text()
    kinds = [a["kind"] for a in logged.value.request.post_data_json["actions"]]
    assert "reason" in kinds and kinds[-1] == "decide", kinds
    with stack.client("admin") as http:
        human = http.get("/api/admin/dashboard").json()["human_time"]
    assert human["verifications"] == 1
    assert not t.errors, t.errors
