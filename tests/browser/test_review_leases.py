"""A reviewer's note is never lost to the Back button or a lease: one that lapsed while the server was
unreachable is re-taken when it answers again (the sample still free) and the note goes with the decision;
when someone else took the sample meanwhile, a banner says so with one button to go on, and the new holder
sees none of the note. Real browser, real API, real worker (it fits the two samples)."""

from __future__ import annotations

import pytest
from sqlalchemy import text

from tests.browser.conftest import sign_in
from tests.browser.test_drafts import lapse_lease
from tests.support.annotate import clicks_body, queue_for_annotation, wait_until

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _in_review(stack, count: int) -> None:
    queue_for_annotation(stack, count)
    with stack.client("annotator") as http:
        for _ in range(count):
            task = http.post("/api/annotate/next").json()
            response = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions",
                                 json=clicks_body(stack, task))
            assert response.status_code == 201, response.text
    with stack.client("admin") as http:
        wait_until(lambda: http.get("/api/admin/rounds/statistics").json()["samples_by_state"].get("in_review")
                   == count, 300, "the fits of the annotated samples", stack)


def _saved(page, revision: int) -> None:
    page.wait_for_function(f"() => Number(document.body.dataset.draftSaved) >= {revision} && "
                           "document.body.dataset.draftState === 'saved'", timeout=30_000)


def test_a_lease_lapsed_while_offline_is_retaken_and_a_lost_one_shows_a_banner(live_stack, tab):
    stack = live_stack(frames=2, queue_for_annotation=False)
    _in_review(stack, 2)
    t = tab()
    user = stack.users["reviewer"]
    sign_in(t, stack.base_url, user.email, user.password, "review")
    page = t.page
    first = int(page.get_attribute("body", "data-sample"))
    page.keyboard.press("r")
    page.keyboard.type("wrist")
    page.go_back()  # at once, before the debounced save: leaving the page saves what is pending
    page.wait_for_function(f"() => document.body.dataset.ready === 'review' && document.body.dataset.sample === "
                           f"'{first}' && document.body.dataset.draft !== undefined && "
                           "document.body.dataset.draft !== 'none'", timeout=60_000)
    assert page.input_value(".reason-input") == "wrist"  # the note came back with the page
    assert page.get_attribute("body", "data-draft") == "1"  # saved once, as the page went
    page.click(".reason-input")  # the caret at its end, typing goes on
    page.keyboard.press("End")

    # The server unreachable (every API request fails) while the lease lapses; the note typed meanwhile is
    # saved once it answers again: the save is refused as lapsed, the lease re-taken, the save repeated.
    page.route("**/api/**", lambda route: route.abort("connectionrefused"))
    page.keyboard.type(" too far left")
    page.wait_for_function("() => document.body.dataset.draftState === 'error'", timeout=30_000)
    lapse_lease(stack, first)
    page.unroute("**/api/**")
    _saved(page, 2)
    assert page.get_attribute("body", "data-lease") is None and page.is_hidden(".lease-banner")
    with stack.session_factory()() as session:
        draft = session.execute(text("SELECT payload FROM drafts WHERE sample_id = :s"), {"s": first}).scalar_one()
    assert "wrist too far left" in str(draft), draft
    lapse_lease(stack, first)
    page.keyboard.press("Enter")  # refused as lapsed, re-taken, decided
    page.wait_for_function(f"() => document.body.dataset.sample !== '{first}'", timeout=30_000)
    second = int(page.get_attribute("body", "data-sample"))
    with stack.session_factory()() as session:
        stored = session.execute(text("SELECT decision, reason FROM decisions WHERE sample_id = :s"),
                                 {"s": first}).one()
    assert tuple(stored) == ("reject", "wrist too far left")

    # The second sample's lease lapses and an admin (who may review) takes it: the reviewer's next save is
    # refused, the lease cannot be re-taken, a banner says so; the admin sees none of the reviewer's note.
    page.keyboard.press("n")
    page.keyboard.type("thumb")
    _saved(page, 1)
    lapse_lease(stack, second)
    admin = tab()
    sign_in(admin, stack.base_url, stack.users["admin"].email, stack.users["admin"].password, "admin")
    admin.page.goto(stack.base_url + "/#/review")
    admin.page.wait_for_selector("body[data-ready=review]", state="attached", timeout=60_000)
    assert admin.page.get_attribute("body", "data-sample") == str(second)
    assert admin.page.evaluate("() => document.body.dataset.reason ?? null") is None
    assert admin.page.get_attribute("body", "data-draft") == "none"
    page.keyboard.type(" tip")
    page.wait_for_selector(".lease-banner:not([hidden]) button.next-task", timeout=30_000)
    assert f"Sample {second} is no longer yours" in page.inner_text(".lease-banner")
    t.shot("review-lease-lost-banner")
    page.click(".lease-banner button.next-task")
    page.wait_for_selector("body[data-ready=review-empty]", state="attached", timeout=30_000)
    assert page.is_hidden(".lease-banner")
    assert not t.errors and not admin.errors, (t.errors, admin.errors)
