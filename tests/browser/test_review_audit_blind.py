"""A blind audit on the review page (issue 40, services.review.label_audits): a label a reviewer accepted comes back to
another reviewer as any review task: the page says neither that it was accepted, nor by whom, nor what the heuristic
said; the decision is the audit's verdict. Real browser, real API, real worker (it fits the sample)."""

from __future__ import annotations

import pytest

from tests.browser.conftest import sign_in
from tests.browser.test_review_leases import _in_review

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_an_audit_looks_like_any_review_task(live_stack, tab):
    stack = live_stack(frames=1, queue_for_annotation=False)
    with stack.client("admin") as http:
        assert http.put("/api/admin/quality/settings", json={"audit_share": 1.0}).status_code == 200
    _in_review(stack, 1)
    reviewer = stack.users["reviewer"]
    with stack.client("reviewer") as http:
        task = http.post("/api/review/next").json()
        accepted = http.post(f"/api/review/samples/{task['sample_id']}/decision", json={"decision": "accept"})
        assert accepted.status_code == 201 and accepted.json()["state"] == "accepted", accepted.text
        assert http.post("/api/review/next").status_code == 204  # nobody audits their own accept
    admin = stack.users["admin"]
    t = tab()
    sign_in(t, stack.base_url, admin.email, admin.password, "admin")
    page = t.page
    page.goto(stack.base_url + "/#/review")
    page.wait_for_selector(f"body[data-ready=review][data-sample='{task['sample_id']}']", state="attached",
                           timeout=60_000)
    side = page.inner_text(".sample-head").lower() + " " + page.inner_text("dl.facts").lower()
    for giveaway in ("accepted", "heuristic", "audit", reviewer.email.lower(), "passed"):
        assert giveaway not in side, (giveaway, side)
    assert page.locator("button.accept").is_visible() and page.locator("button.annotate").is_visible()
    page.keyboard.press("a")
    page.wait_for_selector("body[data-ready=review-empty]", state="attached", timeout=60_000)
    with stack.client("admin") as http:
        audits = http.get("/api/admin/quality/audits").json()["audits"]
        figures = http.get("/api/admin/quality").json()["streams"]["annotated"]
    assert [(a["sample_id"], a["verdict"]) for a in audits] == [(task["sample_id"], "correct")]
    assert figures["audited"] == 1 and figures["wrong"] == 0
    # The admin page's label-quality section shows the audit per stream.
    page.goto(stack.base_url + "/#/admin")
    page.wait_for_selector("#quality[data-ready=quality]", state="attached", timeout=60_000)
    assert page.inner_text(".quality-streams tr[data-stream=annotated] td.audited") == "1"
    assert page.inner_text(".quality-streams tr[data-stream=annotated] td.rate") == "0.0 %"
    assert page.locator(".quality-rounds tr[data-round='0'][data-stream=annotated]").count() == 1
    # People over time: the reviewer's and the auditor's overturned share this week (one decision each, the audit
    # agreed), beside the team median.
    rows = page.locator(".quality-people tr[data-figure=overturned_rate]")
    assert rows.count() == 2
    assert rows.locator("td.current").all_inner_texts() == ["0.0 % (1)"] * 2
    assert rows.locator("td.median").all_inner_texts() == ["0.0 %"] * 2
