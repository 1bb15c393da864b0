"""The review page keeps the fit's distance to points placed by hand apart from its distance to points the
annotator accepted from proposals (a fit lands near the proposal it came from, so counted together they
flatter it), and draws accepted points as proposals. Real browser, real API, real worker (it fits)."""

from __future__ import annotations

import pytest

from tests.browser.conftest import sign_in
from tests.support.annotate import clicks_body, queue_for_annotation, wait_until

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_the_review_page_shows_residuals_to_clicks_apart_from_accepted_proposals(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    queue_for_annotation(stack, 1)
    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()
        body = clicks_body(stack, task)
        accepted_views = {v["id"] for v in task["views"][:3]}  # as if Enter had accepted these views' proposals
        for click in body["clicks"]:
            click["from_proposal"] = click["view_id"] in accepted_views and click["visibility"] == "visible"
        response = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body)
        assert response.status_code == 201, response.text
    with stack.client("admin") as http:
        wait_until(lambda: http.get("/api/admin/rounds/statistics").json()["samples_by_state"].get("in_review"),
                   300, "the fit of the annotated sample", stack)
    n_accepted = sum(1 for c in body["clicks"] if c["from_proposal"])
    n_clicked = sum(1 for c in body["clicks"] if c["visibility"] == "visible") - n_accepted
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    assert page.get_attribute("body", "data-sample") == str(task["sample_id"])
    clicked = page.inner_text(".review-side .residual-clicked")
    accepted = page.inner_text(".review-side .residual-accepted")
    assert f"over {n_clicked} points placed by hand" in clicked, clicked
    assert f"over {n_accepted} accepted proposals" in accepted, accepted
    banner = page.inner_text(".fit-banner")
    assert "vs clicks" in banner and "vs accepted proposals" in banner, banner
    t.shot("review-residuals-by-origin")
    assert not t.errors, t.errors
