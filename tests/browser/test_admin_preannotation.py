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


def test_the_import_form_pre_annotates_in_the_same_action(live_stack, tab):
    """The import form's "pre-annotate" box is checked exactly when the detector can run (else disabled, its
    reason shown); importing with it queues round 0's job, whose live bar the page shows until the worker ends it;
    the job routes every sample (none left unlabeled), and the annotators' first sample shows the detector fit's
    and the detector's keypoints as proposals (the stack's own project stays unlabeled, out of their queue)."""
    stack = live_stack(queue_for_annotation=False)
    with stack.client("admin") as http:
        status = http.get("/api/admin/preannotation").json()
    admin = tab()
    sign_in(admin, stack.base_url, stack.users["admin"].email, stack.users["admin"].password, "admin")
    page = admin.page
    page.wait_for_selector("form.import-form")
    box = page.locator("form.import-form input[name=preannotate]")
    if not status["available"]:
        assert box.is_disabled() and not box.is_checked()
        assert status["reason"] in page.inner_text("#data .import-why")
        return
    assert box.is_enabled() and box.is_checked()
    page.fill("form.import-form input[type=text] >> nth=0", str(stack.capture_dir))
    page.fill("form.import-form input[type=text] >> nth=1", "second")
    page.click("form.import-form button[type=submit]")
    outcome = page.wait_for_selector("#data .import-outcome:has-text('queued')", timeout=60_000).inner_text()
    with stack.client("admin") as http:
        job = next(j for j in http.get("/api/admin/jobs?limit=25").json() if j["kind"] == "preannotate")
    assert f"pre-annotation job {job['id']} queued for 3 samples" in outcome, outcome
    page.wait_for_selector(f".live[data-job='{job['id']}'][data-state=succeeded]", timeout=240_000)
    with stack.client("admin") as http:
        projects = {p["name"]: p for p in http.get("/api/admin/preannotation").json()["projects"]}
    assert projects["second"]["samples"] == 3 and projects["second"]["unlabeled"] == 0
    page.locator("#data").scroll_into_view_if_needed()
    admin.shot("admin-import-preannotated")
    assert not admin.errors, admin.errors
    annotator = tab()
    user = stack.users["annotator"]
    sign_in(annotator, stack.base_url, user.email, user.password, "annotate")
    kinds = annotator.page.eval_on_selector_all(".side [data-source]", "els => els.map((e) => e.dataset.source)")
    assert kinds == ["fit", "detector"], kinds
    annotator.shot("annotate-first-sample-preannotated")
    assert not annotator.errors, annotator.errors
