"""The security headers (issue #13, defect 10) in a real browser: with the Content-Security-Policy of each kind
of page (backend.api.security_headers), the UI's pages, the reviewers' 3D view (viser's client, in its iframe)
and the API docs (Swagger UI from this server) still work, and the browser reports no violation.

A live API process (no worker): one sample is annotated through the API and given a fit as a worker records it,
so the reviewer's page and its 3D view have something to show."""

from __future__ import annotations

import re
import time

import pytest

from tests.browser.conftest import open_3d_view, sign_in
from tests.support.annotate import clicks_body, ground_truth_of

pytestmark = [pytest.mark.browser, pytest.mark.slow]

# Every frame records the violations the browser reports (script, style, worker, connect...).
RECORD_VIOLATIONS = """document.addEventListener("securitypolicyviolation", (e) => {
  (window.__csp = window.__csp || []).push(`${e.effectiveDirective} ${e.blockedURI} ${e.sourceFile}:${e.lineNumber}`);
});"""


def _in_review(stack) -> int:
    """Annotate the first sample through the API and record a fit from its ground truth: it is in review."""
    from backend.services.captures.samples import views_of
    from backend.services.review.verification import HeuristicThresholds
    from workers.tasks import records

    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()
        submitted = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=clicks_body(stack, task))
        assert submitted.status_code == 201, submitted.text
    gt = ground_truth_of(stack, task)
    params = gt.params.to_theta()
    with stack.session_factory().begin() as session:
        views = views_of(session, task["sample_id"], with_masks=False)
        records.record_fit(session, task["sample_id"], params=params.tolist(), keypoints_m=gt.keypoints_3d.tolist(),
                           view_ious={v.id: 0.9 for v in views}, diagnostics={"loss": 0.1},
                           inputs={"submission_ids": [submitted.json()["id"]]}, model_file="handloop-builtin v1",
                           thresholds=HeuristicThresholds())
    return task["sample_id"]


def _violations(tab) -> list[tuple[str, str]]:
    """(frame URL, violation) of every frame of the tab."""
    return [(frame.url, v) for frame in tab.page.frames for v in frame.evaluate("() => window.__csp || []")]


def test_ui_viewer_and_docs_work_under_their_policies(live_stack, tab):
    stack = live_stack(frames=3, worker=False)
    sample_id = _in_review(stack)
    csp_console: list[str] = []

    def open_tab():
        t = tab()
        t.page.context.add_init_script(RECORD_VIOLATIONS)
        t.page.on("console", lambda m: csp_console.append(m.text) if "Content Security Policy" in m.text else None)
        return t

    # The reviewer's page, then the 3D view in its iframe: viser's client loads the recording and draws.
    reviewer = open_tab()
    scene_answers = []
    reviewer.page.on("response", lambda r: scene_answers.append(r.status) if "/scene?" in r.url else None)
    sign_in(reviewer, stack.base_url, stack.users["reviewer"].email, stack.users["reviewer"].password, "review")
    page = reviewer.page
    assert page.get_attribute("body", "data-sample") == str(sample_id)
    open_3d_view(page)
    viewer = page.frame_locator("iframe.viewer-frame")
    viewer.locator("canvas").first.wait_for(timeout=60_000)  # the client ran: its script and wasm were allowed
    deadline = time.monotonic() + 120
    while not scene_answers and time.monotonic() < deadline:  # the client fetches the recording once it runs
        page.wait_for_timeout(200)
    assert scene_answers and set(scene_answers) <= {200, 304}, scene_answers
    reviewer.shot("csp-review-3d")

    # The annotator's and the admin's pages.
    with stack.client("admin") as http:
        http.post("/api/admin/samples/queue-for-annotation", json={"sample_ids": [sample_id + 1]})
    annotator = open_tab()
    sign_in(annotator, stack.base_url, stack.users["annotator"].email, stack.users["annotator"].password, "annotate")
    annotator.shot("csp-annotate")
    admin = open_tab()
    sign_in(admin, stack.base_url, stack.users["admin"].email, stack.users["admin"].password, "admin")
    admin.shot("csp-admin")

    # Swagger UI from this server renders the published operations.
    docs = open_tab()
    requested_hosts = set()
    docs.page.on("request", lambda r: requested_hosts.add(re.sub(r"^\w+://([^/]+).*$", r"\1", r.url)))
    docs.page.goto(stack.base_url + "/docs")
    docs.page.wait_for_selector(".opblock", timeout=60_000)
    assert docs.page.locator(".opblock").count() >= 30
    docs.shot("csp-docs")
    assert requested_hosts <= {stack.base_url.split("://")[1]}, requested_hosts

    for t in (reviewer, annotator, admin, docs):
        assert not t.errors, t.errors
        assert not _violations(t), _violations(t)
    assert not csp_console, csp_console
