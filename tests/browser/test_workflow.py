"""The product end to end in a real browser, on a live stack (real API process, real Celery worker):
an annotator annotates a sample by clicks and brush and submits; the worker's fit appears on the review
page; a reviewer accepts it with one key; the admin sees the counts change and launches a round whose
progress bar moves to the end. Screenshots of every page in test-output/browser/."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import select

from tests.browser.conftest import SCALE, SCREEN_OF, TASK, WHOLE_SCALE, open_3d_view, sign_in, submit_as_is
from tests.support.annotate import ground_truth_of, queue_for_annotation, wait_until

pytestmark = [pytest.mark.browser, pytest.mark.slow]



# Records every (state, progress) the admin page's live job bar takes, as the page changes it.
RECORD_LIVE_BAR = """() => {
  window.__liveBar = [];
  const note = () => {
    const l = document.querySelector('.live');
    if (!l || !l.dataset.job) return;
    const entry = [l.dataset.state || '', Number(l.dataset.progress || 0)];
    const last = window.__liveBar[window.__liveBar.length - 1];
    if (!last || last[0] !== entry[0] || last[1] !== entry[1]) window.__liveBar.push(entry);
  };
  new MutationObserver(note).observe(document.body, { subtree: true, childList: true, attributes: true,
    attributeFilter: ['data-state', 'data-progress', 'data-job'] });
  note();
}"""


def _state_count(page, state: str) -> int:
    return int(page.inner_text(f".state-card[data-state={state}] .n"))


def annotate_in_browser(tab, stack) -> dict:
    """Clicks in two views at the true positions, proposals accepted in the others with Enter, one brush
    stroke, submitted with Ctrl+Enter. Returns what was submitted."""
    page = tab.page
    sign_in(tab, stack.base_url, stack.users["annotator"].email, stack.users["annotator"].password, "annotate")
    task = page.evaluate(TASK)
    gt = ground_truth_of(stack, task)
    names = list(gt.camera_names)
    clicked = []
    for index, view in enumerate(task["views"][:2]):
        page.click(f".thumb >> nth={index}")
        c = names.index(view["camera"])
        for i, k in enumerate((0, 4, 8, 12, 16, 20)):
            page.keyboard.press(str(i + 1))
            page.mouse.click(*page.evaluate(SCREEN_OF, gt.keypoints_2d[c, k].tolist()))
            clicked.append((view["id"], k))
    for index in range(2, len(task["views"])):
        page.click(f".thumb >> nth={index}")
        page.keyboard.press("Enter")  # accept the points triangulated from the two clicked views
    page.click(".thumb >> nth=0")
    page.keyboard.press("0")
    if page.evaluate(SCALE) > page.evaluate(WHOLE_SCALE) + 1e-9:
        page.keyboard.press("0")  # the view opened on the hand: 0 again shows the whole image for the stroke
    page.keyboard.press("b")
    (x0, y0), (x1, y1) = (page.evaluate(SCREEN_OF, p) for p in ([8.0, 8.0], [40.0, 20.0]))
    page.mouse.move(x0, y0)
    page.mouse.down()
    page.mouse.move(x1, y1, steps=10)
    page.mouse.up()
    state = page.evaluate("""() => { const p = window.__handloop.page;
        return {clicks: p.annotation.toClicks(), edited: p.views.filter((v) => v.maskEdited).map((v) => v.id)}; }""")
    tab.shot("01-annotate-before-submit")
    submit_as_is(page)
    page.wait_for_function(f"() => document.body.dataset.sample !== '{task['sample_id']}'", timeout=30_000)
    tab.shot("02-annotate-next-task")
    state["task"], state["gt"], state["names"] = task, gt, names
    return state


def test_annotate_fit_review_and_round_in_the_browser(live_stack, tab):
    stack = live_stack(frames=4, queue_for_annotation=False)
    queue_for_annotation(stack, 2)  # D_0 candidates; the other samples are what the round predicts on
    annotator = tab()
    sent = annotate_in_browser(annotator, stack)
    task, gt, names = sent["task"], sent["gt"], sent["names"]
    sample_id = task["sample_id"]
    # Every keypoint of every view was set, at the true pixels (clicked or triangulated from two views).
    placed = [c for c in sent["clicks"] if c["visibility"] != "not_annotated"]
    by_view = {v["id"]: v for v in task["views"]}
    errors = [np.hypot(*(np.array([c["x"], c["y"]]) - gt.keypoints_2d[names.index(by_view[c["view_id"]]["camera"]),
                                                                      c["keypoint"]])) for c in placed]
    assert len(placed) >= 40 and max(errors) < 0.5, (len(placed), max(errors))
    assert sent["edited"] == [task["views"][0]["id"]]
    with stack.session_factory()() as session:
        from backend.models.labels import Mask, Submission

        submission = session.execute(select(Submission).where(Submission.sample_id == sample_id)).scalar_one()
        kinds = session.execute(select(Mask.kind).where(Mask.submission_id == submission.id)).scalars().all()
    assert kinds == ["corrected"] and submission.n_clicks == 6 * len(task["views"])

    # The real worker fits it; the review page shows that fit over every view.
    with stack.client("admin") as http:
        wait_until(lambda: http.get("/api/admin/rounds/statistics").json()["samples_by_state"].get("in_review"),
                   300, "the fit of the annotated sample", stack)
    reviewer = tab()
    sign_in(reviewer, stack.base_url, stack.users["reviewer"].email, stack.users["reviewer"].password, "review")
    page = reviewer.page
    assert page.get_attribute("body", "data-sample") == str(sample_id)
    overlay = page.evaluate("() => window.__handloop.page.current.overlay")
    assert overlay["hand_model"]["label"] == "built-in stand-in hand, not MANO"
    assert "built-in stand-in hand, not MANO" in page.inner_text(".fit-banner")
    assert overlay["fit"]["mean_residual_px"] < 3.0  # the worker's fit lands on the clicks
    assert page.locator(".view-card").count() == len(task["views"])
    open_3d_view(page)
    # viser's client loaded and drawing: the frame's document complete and its WebGL canvas in it.
    page.wait_for_function("() => { const d = document.querySelector('iframe.viewer-frame')?.contentDocument;"
                           " return d && d.readyState === 'complete' && d.querySelector('canvas') !== null; }",
                           timeout=60_000)
    # ... and the page drawing again: two animation frames (software WebGL can hold the renderer while the scene
    # loads; the limits only guard a hang).
    page.wait_for_function("() => new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(() =>"
                           " done(true))))", timeout=120_000)
    reviewer.shot("03-review-fit", timeout_ms=120_000)
    page.keyboard.press("a")  # one key accepts
    page.wait_for_function("() => document.body.dataset.ready === 'review-empty' || "
                           f"document.body.dataset.sample !== '{sample_id}'", timeout=30_000)
    reviewer.shot("04-review-after-accept")

    # The admin sees the accepted sample in D_0 and launches round 1 with a live progress bar.
    admin = tab()
    sign_in(admin, stack.base_url, stack.users["admin"].email, stack.users["admin"].password, "admin")
    page = admin.page
    assert _state_count(page, "accepted") == 1
    assert page.inner_text(".rounds-table tr[data-round='0'] td:nth-child(5)") == "1"  # D^l annotated
    assert page.inner_text(".rounds-table tr[data-round='0'] .round-decisions") == "1 accepted"
    admin.shot("05-admin-before-round")
    # Every state and progress the bar shows is recorded as the page sets it (not sampled), from the click on.
    page.evaluate(RECORD_LIVE_BAR)
    page.click("button.launch-round")
    page.wait_for_selector(".live[data-job]", timeout=30_000)
    ended = ("() => ['succeeded', 'failed', 'cancelled'].includes("
             "document.querySelector('.live')?.dataset.state || '')")
    # The bar between its ends, or the job already over (then the record says whether it moved; guards only).
    page.wait_for_function(f"() => {{ const p = Number(document.querySelector('.live')?.dataset.progress || 0);"
                           f" return (0 < p && p < 1) || ({ended})(); }}", timeout=600_000)
    admin.shot("06-admin-round-in-progress")
    page.wait_for_function(ended, timeout=600_000)
    admin.shot("07-admin-round-done")
    seen = [tuple(x) for x in page.evaluate("() => window.__liveBar")]
    state = page.evaluate("() => document.querySelector('.live').dataset.state")
    assert state == "succeeded", (state, seen, stack.stack.worker_log.read_text()[-3000:])
    assert any(0 < p < 1 for _, p in seen), seen  # the bar moved through intermediate values
    page.wait_for_selector(".rounds-table tr[data-round='1']")
    for t in (annotator, reviewer, admin):
        assert not t.errors, t.errors
