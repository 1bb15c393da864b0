"""Clicks land where meant on the annotate page (issue 38, items 1, 2, 7, 9), acted out in a real browser:
- a not-annotated point is unset, not skipped: after every point of the sample was marked not annotated (as a
  sample comes back whose fit failed), 1 and six clicks place the six keypoints, not the wrist six times;
- the counters count placed points ("0/6 · 6 N", not "6/6");
- O after the page moved on to the next view acts on that view, not on the previous view's point;
- a click outside the image places nothing;
- the clock counts working time: an idle gap of minutes adds nothing (Playwright's clock, no waiting)."""

from __future__ import annotations

import pytest

from tests.browser.conftest import SAMPLE, SCREEN_OF, STATUS, TASK, VIEW_AND_KEYPOINT, VIEW_HEIGHT, sign_in

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CLICK = "([v, k]) => { const p = window.__handloop.page; return p.annotation.get(p.views[v].id, k); }"
SPARSE = [0, 4, 8, 12, 16, 20]


def whole_view(page, zoom: float = 1.0) -> None:
    """The whole image in the view (then zoomed about the canvas centre by `zoom`), drawn."""
    page.evaluate("""(zoom) => { const p = window.__handloop.page; p.fitView({whole: true});
      const r = p.canvas.getBoundingClientRect(); p.vp.zoomAt(zoom, r.width / 2, r.height / 2); p.renderNow(true); }""",
                  zoom)


def click_at(page, u: float, v: float, zoom: float = 1.0) -> None:
    whole_view(page, zoom)
    page.mouse.click(*page.evaluate(SCREEN_OF, [u, v]))


def test_clicks_set_not_annotated_points_counters_count_placed_o_stays_in_view_nothing_outside(live_stack, tab):
    stack = live_stack(worker=False)
    t = tab()
    user = stack.users["annotator"]
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    page = t.page
    n_views = page.evaluate("() => document.querySelectorAll('.thumbs .thumb').length")
    total = 6 * n_views

    # Every point of every view marked not annotated: N picks the next undecided one each time.
    for _ in range(total):
        page.keyboard.press("n")
    assert {page.evaluate(STATUS, [v, k]) for v in range(n_views) for k in SPARSE} == {"not_annotated"}
    # Item 9: nothing is placed, so nothing is done ("6/6" and "48/48" before).
    label = page.inner_text(".thumb >> nth=0")
    assert "0/6 · 6 N" in label, label
    assert f"0/{total} keypoints placed · {total} not annotated" in page.inner_text(".totals")

    # Item 1: back to view 1, 1 and six clicks: six keypoints placed where clicked (before, only the wrist moved,
    # ending on the last click). After the last one the page moves on to the next view.
    page.click(".thumb >> nth=0")
    page.keyboard.press("1")
    where = {k: (20.0 + 20.0 * i, 40.0 + 8.0 * (i % 2)) for i, k in enumerate(SPARSE)}
    for k in SPARSE:
        click_at(page, *where[k])
    for k in SPARSE:
        c = page.evaluate(CLICK, [0, k])
        assert c["visibility"] == "visible" and (c["x"], c["y"]) == pytest.approx(where[k], abs=0.5), (k, c)
    assert "6/6" in page.inner_text(".thumb >> nth=0")
    assert f"6/{total} keypoints placed · {total - 6} not annotated" in page.inner_text(".totals")
    assert page.evaluate(VIEW_AND_KEYPOINT) == [1, 0]

    # Item 7: O now acts on view 2 (shown), not on view 1's pinky placed just before the page moved on.
    page.keyboard.press("o")
    assert page.evaluate(STATUS, [0, 20]) == "visible"
    assert "O/N: wrist" in page.inner_text(".hud") and "(just placed)" not in page.inner_text(".hud")

    # Item 2: a click left of the image (zoomed out, so the canvas shows beyond it) places nothing.
    height = page.evaluate(VIEW_HEIGHT)
    click_at(page, -22.0, height / 2, zoom=0.5)
    assert page.evaluate(STATUS, [1, 0]) == "not_annotated"
    assert page.evaluate("() => document.body.dataset.refused") == "outside"
    assert "outside" in page.inner_text(".toasts")
    click_at(page, 30.0, 30.0)  # on the image: placed
    assert page.evaluate(STATUS, [1, 0]) == "visible"


def test_the_clock_counts_no_idle_gap(live_stack, tab):
    stack = live_stack(worker=False)
    t = tab()
    page = t.page
    page.clock.install()
    user = stack.users["annotator"]
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    spent = lambda: page.evaluate("() => window.__handloop.page.timer.spentSeconds()")  # noqa: E731
    clock = lambda: page.inner_text(".sample-head .clock")  # noqa: E731
    page.keyboard.press("n")  # an action: the wrist not annotated
    start = spent()
    page.clock.run_for(10_000)  # looking at the image for 10 s: work, counted in full
    page.keyboard.press("n")
    assert spent() == pytest.approx(start + 10, abs=2)
    page.clock.run_for(10 * 60_000)  # ten minutes away from the desk
    assert "paused: no input for 30 s" in clock(), clock()
    page.keyboard.press("n")
    # Nothing of the idle gap counts (before: 30 s of it did).
    assert spent() == pytest.approx(start + 10, abs=2)
    durations = page.evaluate("() => window.__handloop.page.timer.actions.map((a) => a.duration_ms)")
    assert sum(durations) / 1000 == pytest.approx(spent(), abs=0.5)


def _sent_back_with_a_true_fit(stack) -> dict:
    """One sample annotated from the truth, fitted with the true hand (as a worker records it) and sent back by
    the reviewer: the annotate page then offers the fit's proposals with the keypoints its mesh hides."""

    from backend.services.review.verification import HeuristicThresholds
    from tests.support.annotate import clicks_body, ground_truth_of
    from workers.tasks import records

    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()
        body = clicks_body(stack, task)  # in two views only: the others come back with nothing set
        body["clicks"] = [c for c in body["clicks"] if c["view_id"] in {v["id"] for v in task["views"][:2]}]
        submitted = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body)
        assert submitted.status_code == 201, submitted.text
    gt = ground_truth_of(stack, task)
    with stack.session_factory().begin() as session:
        records.record_fit(session, task["sample_id"], params=gt.params.to_theta().tolist(),
            keypoints_m=gt.keypoints_3d.tolist(),
            view_ious={v["id"]: 0.9 for v in task["views"]}, diagnostics={}, inputs={"submission_ids": [
                submitted.json()["id"]]}, model_file="handloop-builtin v1", thresholds=HeuristicThresholds())
    with stack.client("reviewer") as http:
        assert http.post("/api/review/next").json()["sample_id"] == task["sample_id"]
        decided = http.post(f"/api/review/samples/{task['sample_id']}/decision",
                            json={"decision": "annotate", "reason": "mark the hidden ones occluded"})
        assert decided.status_code == 201, decided.text
    return {"task": task, "gt": gt}


def test_enter_accepts_what_the_fits_mesh_hides_as_occluded_and_o_flips_one(live_stack, tab):
    """Item 10: occlusion in one gesture. Confident proposals at the true keypoints (an MVNet-like source added
    to the API's answer, as in test_proposals) and the fit's per-view flags from the server: Enter accepts the
    hidden ones as occluded (before: all visible, then a digit and O per hidden point); a digit and O flip one."""
    import json

    stack = live_stack(worker=False, frames=3)
    made = _sent_back_with_a_true_fit(stack)
    gt, sid = made["gt"], made["task"]["sample_id"]
    names = list(gt.camera_names)
    served: dict = {}

    def with_network(route) -> None:
        response = route.fetch()
        body = response.json()
        views = {str(c["view_id"]): gt.keypoints_2d[names.index(c["camera"])].round(2).tolist()
                 for c in body["cameras"]}
        body["sources"].insert(0, {"kind": "mvnet", "label": "MVNet (test)", "confidences": [0.9] * 21, "views": views})
        served[body["sample_id"]] = body
        route.fulfill(response=response, body=json.dumps(body))

    t = tab()
    page = t.page
    page.route("**/proposals", with_network)
    user = stack.users["annotator"]
    sign_in(t, stack.base_url, user.email, user.password, "annotate")
    assert page.evaluate(SAMPLE) == sid
    fit = next(s for s in served[sid]["sources"] if s["kind"] == "fit")
    views = [(v["id"], v["width"], v["height"]) for v in page.evaluate(TASK)["views"]]

    def inside(view_id: int, k: int) -> bool:
        p = next(s for s in served[sid]["sources"] if s["kind"] == "mvnet")["views"][str(view_id)][k]
        w, h = next((w, h) for v, w, h in views if v == view_id)
        return -0.5 <= p[0] <= w - 0.5 and -0.5 <= p[1] <= h - 0.5

    # Of the views with nothing set, the one whose fit hides the most of the six keypoints.
    index = max(range(2, len(views)), key=lambda i: sum(fit["hidden"][str(views[i][0])][k] for k in SPARSE
                                                      if inside(views[i][0], k)))
    view_id = views[index][0]
    hidden = {k for k in SPARSE if fit["hidden"][str(view_id)][k] and inside(view_id, k)}
    shown = {k for k in SPARSE if inside(view_id, k)} - hidden
    assert hidden, "the true hand hides none of the keypoints in any view"
    if index:
        page.click(f".thumb >> nth={index}")
    assert "hidden" in page.inner_text(".kp-list")
    actions_before = page.evaluate("() => window.__handloop.page.timer.actions.length")
    page.keyboard.press("Enter")
    got = {k: page.evaluate(STATUS, [index, k]) for k in SPARSE}
    assert {k for k, s in got.items() if s == "occluded"} == hidden, got
    assert {k for k, s in got.items() if s == "visible"} == shown, got
    # One key for all of them (each acceptance is logged as one "accept").
    logged = page.evaluate("() => window.__handloop.page.timer.actions.map((a) => a.kind)")[actions_before:]
    assert logged.count("accept") == len(hidden) + len(shown) and "occlude" not in logged, logged
    # A digit and O flip one the mesh got wrong (back on that view: Enter moved on to the next one).
    page.click(f".thumb >> nth={index}")
    k = sorted(hidden)[0]
    page.keyboard.press(str(SPARSE.index(k) + 1))
    page.keyboard.press("o")
    assert page.evaluate(STATUS, [index, k]) == "visible"
