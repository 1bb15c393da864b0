"""Clicks land where meant on the annotate page (issue 38, items 1, 2, 7, 9), acted out in a real browser:
- a not-annotated point is unset, not skipped: after every point of the sample was marked not annotated (as a
  sample comes back whose fit failed), 1 and six clicks place the six keypoints, not the wrist six times;
- the counters count placed points ("0/6 · 6 N", not "6/6");
- O after the page moved on to the next view acts on that view, not on the previous view's point;
- a click outside the image places nothing;
- the clock counts working time: an idle gap of minutes adds nothing (Playwright's clock, no waiting)."""

from __future__ import annotations

import pytest

from tests.browser.conftest import sign_in

pytestmark = [pytest.mark.browser, pytest.mark.slow]

SCREEN_OF = """([u, v]) => { const p = window.__handloop.page; const r = p.canvas.getBoundingClientRect();
  const s = p.vp.toScreen(u, v); return [r.left + s[0], r.top + s[1]]; }"""
CLICK = "([v, k]) => { const p = window.__handloop.page; return p.annotation.get(p.views[v].id, k); }"
STATUS = "([v, k]) => { const p = window.__handloop.page; return p.annotation.status(p.views[v].id, k); }"
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
    n_views = page.evaluate("() => window.__handloop.page.views.length")
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
    assert page.evaluate("() => [window.__handloop.page.viewIndex, window.__handloop.page.keypoint]") == [1, 0]

    # Item 7: O now acts on view 2 (shown), not on view 1's pinky placed just before the page moved on.
    page.keyboard.press("o")
    assert page.evaluate(STATUS, [0, 20]) == "visible"
    assert "O/N: wrist" in page.inner_text(".hud") and "(just placed)" not in page.inner_text(".hud")

    # Item 2: a click left of the image (zoomed out, so the canvas shows beyond it) places nothing.
    height = page.evaluate("() => window.__handloop.page.view.height")
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
