"""The admin page does not mislead: a round cannot be launched below the minimum of accepted labels (the
button says why in plain words, the API refuses with 409 and writes nothing); leased samples are counted
apart from free ones; jobs show their sample, creation time, duration and how they ended."""

from __future__ import annotations

import pytest

from tests.browser.conftest import sign_in

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_the_launch_button_says_why_not_and_the_counts_show_leases(live_stack, tab):
    stack = live_stack(worker=False, round_min_training_samples=2)
    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()  # one sample on an annotator's screen
    t = tab()
    user = stack.users["admin"]
    sign_in(t, stack.base_url, user.email, user.password, "admin")
    page = t.page
    assert page.is_disabled("button.launch-round")
    why = page.inner_text(".launch-why")
    assert "0 accepted so far, at least 2 needed" in why and "Accept 2 more in review first" in why, why
    overview = page.inner_text("#overview")
    assert "to annotate (+1 being annotated)" in overview, overview
    headers = page.eval_on_selector_all("#jobs th", "els => els.map((e) => e.textContent)")
    assert headers[:6] == ["id", "kind", "sample", "state", "created", "took"], headers
    with stack.client("admin") as http:
        refused = http.post("/api/admin/rounds", json={"note": "too early"})
        assert refused.status_code == 409 and "at least 2 needed" in refused.json()["detail"]
        assert http.get("/api/admin/rounds").json() == []  # nothing written: no round completed, none opened
    t.shot("admin-launch-refused")
    assert task["sequence"] == "seq000"
    assert not t.errors, t.errors
