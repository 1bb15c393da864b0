"""The admin page's round-0 pre-annotation form and the reliability plots, in a real browser on a live stack:
the button is enabled exactly when the server says the detector can run (else disabled, its reason shown),
and the reliability section draws one figure per confidence source without page errors."""

from __future__ import annotations

import pytest

from tests.browser.conftest import sign_in

pytestmark = [pytest.mark.browser]


def test_the_admin_sees_the_pre_annotation_form_and_the_reliability_figures(live_stack, tab):
    stack = live_stack(worker=False, queue_for_annotation=False)
    with stack.client("admin") as http:
        status = http.get("/api/admin/preannotation").json()
    admin = tab()
    sign_in(admin, stack.base_url, stack.users["admin"].email, stack.users["admin"].password, "admin")
    page = admin.page
    page.wait_for_selector("form.preannotate")
    page.wait_for_selector("#reliability figure[data-source=mvnet]")
    button = page.locator("button.preannotate-button")
    options = page.locator("form.preannotate select[name=project] option").all_inner_texts()
    assert options == ["live (3 unlabeled)"]
    # The samples the reviewers' queue does not take stay for round 1 unless the admin chooses otherwise.
    assert page.locator("form.preannotate select[name=rest]").input_value() == "keep"
    if status["available"]:
        assert button.is_enabled()
    else:
        assert button.is_disabled() and status["reason"] in page.inner_text("form.preannotate")
    figures = page.locator("#reliability figure").all_inner_texts()
    assert len(figures) == 3 and all("no data yet" in f for f in figures), figures
    admin.shot("admin-preannotation")
    assert not admin.errors, admin.errors
