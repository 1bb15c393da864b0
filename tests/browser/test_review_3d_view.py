"""The review page's 3D view (viser's client in a same-origin iframe, whose software WebGL shares the page's
main thread) goes away the moment a decision is made and comes back for the next sample, so it does not
hold up the decision or the next sample's drawing. Real browser, real API, real worker (it fits)."""

from __future__ import annotations

import pytest

from tests.browser.conftest import open_3d_view, sign_in
from tests.support.annotate import clicks_body, queue_for_annotation, wait_until

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_the_3d_view_is_released_at_a_decision_and_started_again_for_the_next_sample(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    queue_for_annotation(stack, 2)
    with stack.client("annotator") as http:
        for _ in range(2):
            task = http.post("/api/annotate/next").json()
            response = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions",
                                 json=clicks_body(stack, task))
            assert response.status_code == 201, response.text
    with stack.client("admin") as http:
        wait_until(lambda: http.get("/api/admin/rounds/statistics").json()["samples_by_state"].get("in_review") == 2,
                   300, "the fits of the two annotated samples", stack)
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    first = page.get_attribute("body", "data-sample")
    open_3d_view(page, loaded=True)  # its document loaded: the page listens for keys in it too
    held = []  # the decision's request, answered only once the test has looked
    page.route("**/api/review/samples/*/decision", lambda route: held.append(route))
    # Waits on the request itself (the limit only guards a hang: a loaded machine once took over 10 s).
    with page.expect_request("**/api/review/samples/*/decision", timeout=120_000):
        page.keyboard.press("a")
    page.wait_for_selector(".viewer-wait", state="attached", timeout=30_000)
    assert held, "the decision was not held by the test's route"
    assert page.query_selector("iframe.viewer-frame") is None  # gone while the decision is on its way
    assert page.query_selector(".viewer-wait") is not None
    held[0].continue_()
    page.wait_for_function(f"() => document.body.dataset.sample !== '{first}'", timeout=30_000)
    second = page.get_attribute("body", "data-sample")
    page.wait_for_selector("iframe.viewer-frame", timeout=30_000)  # the next sample's scene
    src = page.get_attribute("iframe.viewer-frame", "src")
    assert f"samples%2F{second}%2Fscene" in src or f"samples/{second}/scene" in src, src
    assert not t.errors, t.errors
