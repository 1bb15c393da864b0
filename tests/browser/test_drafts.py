"""Work is never lost: what an annotator did is restored after a reload, the Back button and a new login in
another tab; leaving with unsaved work asks first; a lapsed lease is re-taken when the sample is still free
(and the work submits), and when someone else took it a banner says so, with one button to go on, and the
new holder never sees the old work. Real browser, real API process (no worker needed)."""

from __future__ import annotations

import pytest
from sqlalchemy import text

from backend.db.base import utcnow
from tests.browser.conftest import SAMPLE, SCREEN_OF, sign_in, submit_as_is

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CLICKS = """() => { const p = window.__handloop.page; const out = [];
  for (const [view, m] of p.annotation.clicks) for (const [k, c] of m) out.push([view, k, c.x, c.y, c.visibility]);
  return out.sort((a, b) => a[0] - b[0] || a[1] - b[1]); }"""
# The view opens cropped to the hand; these tests click anywhere in the image, so they show it whole.
WHOLE = "() => { const p = window.__handloop.page; p.fitView({whole: true}); p.renderNow(true); }"


def place(page, view_index: int, count: int) -> None:
    """Click `count` keypoints (wrist, thumb, ...) in one view, 12 image px apart along a row."""
    page.click(f".thumb >> nth={view_index}")
    page.evaluate(WHOLE)
    for i in range(count):
        page.keyboard.press(str(i + 1))
        page.mouse.click(*page.evaluate(SCREEN_OF, [20.0 + 12.0 * i, 30.0 + 5.0 * view_index]))


def wait_saved(page, revision: int | None = None) -> None:
    page.wait_for_selector("body[data-draft-state=saved]", state="attached", timeout=30_000)
    if revision is not None:
        page.wait_for_function(f"() => Number(document.body.dataset.draftSaved) >= {revision}", timeout=30_000)


def wait_shown(page) -> None:
    page.wait_for_selector("body[data-ready=annotate]", state="attached", timeout=60_000)


def lapse_lease(stack, sample_id: int) -> None:
    from datetime import timedelta

    with stack.session_factory().begin() as session:
        session.execute(text("UPDATE samples SET lease_expires_at = :t WHERE id = :i"),
                        {"t": utcnow() - timedelta(seconds=5), "i": sample_id})


def sign_in_annotator(tab, stack) -> None:
    user = stack.users["annotator"]
    sign_in(tab, stack.base_url, user.email, user.password, "annotate")


def start_saved(live_stack, tab, clicks: int):
    """A signed-in annotator with `clicks` keypoints placed in the first view and saved (revision 1)."""
    stack = live_stack(worker=False)
    t = tab()
    sign_in_annotator(t, stack)
    place(t.page, 0, clicks)
    wait_saved(t.page, 1)
    return stack, t, t.page, t.page.evaluate(SAMPLE)


KEPT = """() => Object.keys(sessionStorage).filter((k) => k.startsWith('handloop.unsavedDraft.'))
  .map((k) => [k, JSON.parse(sessionStorage.getItem(k))])"""


def test_a_reload_loses_no_click(live_stack, tab):
    stack = live_stack(worker=False)
    t = tab()
    sign_in_annotator(t, stack)
    page = t.page
    place(page, 0, 6)
    place(page, 1, 3)
    page.keyboard.press("o")  # the last one placed, now occluded: state beyond positions survives too
    wait_saved(page)
    before, sample, submission = page.evaluate(CLICKS), page.evaluate(SAMPLE), page.evaluate(
        "() => window.__handloop.page.submissionId")
    assert len(before) == 9
    page.reload()
    wait_shown(page)
    assert page.evaluate(SAMPLE) == sample
    assert page.evaluate(CLICKS) == before
    assert page.evaluate("() => window.__handloop.page.submissionId") == submission  # a retried submit stays one
    assert page.get_attribute("body", "data-draft") not in (None, "none")
    assert not t.errors, t.errors


def test_back_and_a_new_login_in_another_tab_lose_no_click(live_stack, tab):
    stack = live_stack(worker=False)
    first = tab()
    sign_in_annotator(first, stack)
    page = first.page
    place(page, 0, 4)
    before, sample = page.evaluate(CLICKS), page.evaluate(SAMPLE)
    page.go_back()  # at once, before the debounced save: leaving the page saves what is pending
    page.wait_for_function(f"() => window.__handloop.page && window.__handloop.page.task && "
                           f"window.__handloop.page.task.sample_id === {sample} && "
                           "document.body.dataset.draft !== 'none'", timeout=60_000)
    assert page.evaluate(CLICKS) == before
    place(page, 1, 2)
    wait_saved(page)
    before = page.evaluate(CLICKS)
    assert len(before) == 6
    other = tab()  # another browser (its own session storage): a new login
    sign_in_annotator(other, stack)
    assert other.page.evaluate(SAMPLE) == sample
    assert other.page.evaluate(CLICKS) == before
    assert not first.errors and not other.errors, (first.errors, other.errors)


def test_leaving_with_unsaved_work_asks_first(live_stack, tab):
    stack = live_stack(worker=False)
    t = tab()
    sign_in_annotator(t, stack)
    page = t.page
    page.route("**/draft", lambda route: None if route.request.method == "PUT" else route.continue_())  # held
    dialogs: list[str] = []

    def answer(dialog) -> None:
        dialogs.append(dialog.type)
        dialog.accept()

    page.on("dialog", answer)
    place(page, 0, 1)
    page.wait_for_selector("body[data-draft-state=saving]", state="attached", timeout=30_000)
    page.reload()
    wait_shown(page)
    assert dialogs == ["beforeunload"]


def test_a_reload_while_a_save_is_in_flight_loses_no_click(live_stack, tab):
    # The save on its way when the page reloads is cancelled by the browser; if it had not reached the
    # server, the clicks since the last saved revision would be gone unless the page kept and resent them.
    _stack, t, page, sample = start_saved(live_stack, tab, 2)
    held: list = []

    def hold_first_put(route) -> None:
        if route.request.method == "PUT" and not held:
            held.append(route)  # never answered
        else:
            route.continue_()

    page.route("**/draft", hold_first_put)
    page.on("dialog", lambda dialog: dialog.accept())
    place(page, 1, 3)
    page.wait_for_selector("body[data-draft-state=saving]", state="attached", timeout=30_000)
    page.wait_for_function("() => document.body.dataset.draftState === 'saving' && "
                           "!window.__handloop.page.drafts.dirty", timeout=30_000)  # nothing beyond the held PUT
    before = page.evaluate(CLICKS)
    assert len(before) == 5 and len(held) == 1
    page.reload()
    wait_shown(page)
    assert page.evaluate(SAMPLE) == sample
    assert page.evaluate(CLICKS) == before
    # Saved at revision 2: by the keepalive resend as the page went, or restored from the tab and saved now.
    page.wait_for_function("() => Math.max(Number(document.body.dataset.draft) || 0, "
                           "Number(document.body.dataset.draftSaved) || 0) >= 2", timeout=30_000)
    page.unroute("**/draft")
    page.reload()  # and the server has it all
    wait_shown(page)
    assert page.evaluate(CLICKS) == before
    assert page.evaluate(KEPT) == []
    assert not t.errors, t.errors


def test_a_lapsed_lease_on_a_free_sample_is_retaken_and_the_work_submits(live_stack, tab):
    stack, t, page, sample = start_saved(live_stack, tab, 3)
    lapse_lease(stack, sample)
    place(page, 0, 4)  # the save is refused (lease expired), the lease taken again, the save repeated
    page.wait_for_function("() => Number(document.body.dataset.draftSaved) >= 2 && "
                           "document.body.dataset.draftState === 'saved'", timeout=30_000)
    assert page.get_attribute("body", "data-lease") is None
    lapse_lease(stack, sample)
    submit_as_is(page)  # refused as expired, re-taken, submitted (the points not set: asked first)
    page.wait_for_function(f"() => document.body.dataset.sample !== '{sample}' || "
                           "document.body.dataset.ready === 'annotate-empty'", timeout=30_000)
    with stack.session_factory()() as session:
        placed = session.execute(text("SELECT count(*) FROM clicks WHERE sample_id = :s AND visibility != "
                                      "'not_annotated'"), {"s": sample}).scalar_one()
        drafts = session.execute(text("SELECT count(*) FROM drafts WHERE sample_id = :s"), {"s": sample}).scalar_one()
    assert (placed, drafts) == (4, 0)  # 0 clicks lost; the draft went with the submission
    assert not t.errors, t.errors


def test_a_lease_taken_by_someone_else_shows_a_banner_and_the_work_travels(live_stack, tab):
    # Issue 38 item 4 (this test said the opposite before: "the new holder never sees the old work", and the new
    # annotator redid 35 points): the saved work goes with the sample; the banner and the panel say the same.
    stack = live_stack(worker=False)
    t = tab()
    sign_in_annotator(t, stack)
    page = t.page
    place(page, 0, 2)
    wait_saved(page, 1)
    sample = page.evaluate(SAMPLE)
    left = page.evaluate(CLICKS)
    lapse_lease(stack, sample)
    admin = tab()  # someone else (an admin may annotate) gets the lapsed sample
    user = stack.users["admin"]
    sign_in(admin, stack.base_url, user.email, user.password, "admin")
    admin.page.goto(stack.base_url + "/#/annotate")
    wait_shown(admin.page)
    assert admin.page.evaluate(SAMPLE) == sample
    assert admin.page.evaluate(CLICKS) == left and len(left) == 2  # carried on, not redone
    assert admin.page.get_attribute("body", "data-draft-left-by")
    place(page, 0, 3)  # the save is refused; the lease cannot be taken again
    page.wait_for_selector(".lease-banner:not([hidden]) button.next-task", timeout=30_000)
    banner = page.inner_text(".lease-banner")
    assert "someone else" in banner and "goes with the sample" in banner and "stays saved as your draft" not in banner
    panel = page.inner_text(".draft-state")
    assert "no longer yours" in panel and "retrying" not in panel
    t.shot("drafts-lease-lost-banner")
    page.click(".lease-banner button.next-task")
    page.wait_for_function(f"() => document.body.dataset.sample !== '{sample}' || "
                           "document.body.dataset.ready === 'annotate-empty'", timeout=30_000)
    assert page.is_hidden(".lease-banner")
    assert not t.errors and not admin.errors, (t.errors, admin.errors)


def test_a_lease_lapsed_while_the_server_was_unreachable_loses_no_click(live_stack, tab):
    # Clicks placed while no request gets through (the server down, the network gone) and the lease lapsing
    # meanwhile: when the server answers again the draft is saved (the lease re-taken on the way) and submits.
    stack, t, page, sample = start_saved(live_stack, tab, 2)
    page.route("**/api/**", lambda route: route.abort("connectionrefused"))
    place(page, 1, 3)
    page.wait_for_selector("body[data-draft-state=error]", state="attached", timeout=30_000)
    lapse_lease(stack, sample)
    before = page.evaluate(CLICKS)
    page.unroute("**/api/**")
    page.wait_for_function("() => Number(document.body.dataset.draftSaved) >= 2 && "
                           "document.body.dataset.draftState === 'saved'", timeout=30_000)
    assert page.get_attribute("body", "data-lease") is None and page.is_hidden(".lease-banner")
    page.reload()  # what the server kept is all of it
    wait_shown(page)
    assert page.evaluate(SAMPLE) == sample and page.evaluate(CLICKS) == before and len(before) == 5
    assert not t.errors, t.errors


def test_clicks_made_as_the_token_is_revoked_come_back_after_signing_in_again(live_stack, tab):
    # The token stops working mid-sample (revoked here; expired or a deactivated account answer the same 401):
    # the page signs out, keeps what the server did not take in the tab, and restores and saves it after the
    # annotator signs in again. (No user cache, so the very next request is refused.)
    stack = live_stack(worker=False, auth_cache_seconds=0)
    t = tab()
    sign_in_annotator(t, stack)
    page = t.page
    place(page, 0, 3)
    wait_saved(page, 1)
    sample = page.evaluate(SAMPLE)
    user = stack.users["annotator"]
    with stack.session_factory().begin() as session:
        session.execute(text("UPDATE users SET token_version = token_version + 1 WHERE email = :e"),
                        {"e": user.email})
    held: list = []  # saves wait until both clicks are made (the debounce is no part of the test)
    page.route("**/draft", lambda route: held.append(route) if route.request.method == "PUT" else route.continue_())
    place(page, 1, 2)
    page.unroute("**/draft")
    for route in held:
        route.continue_()  # refused (401): signed out
    page.wait_for_selector("body[data-ready=login]", state="attached", timeout=30_000)
    [(key, kept)] = page.evaluate(KEPT)
    assert key.startswith("handloop.unsavedDraft.annotate.") and key.endswith(f".{sample}"), key
    assert kept["sampleId"] == sample and len(kept["payload"]["clicks"]) == 5, kept
    sign_in_annotator(t, stack)
    assert page.evaluate(SAMPLE) == sample
    before = page.evaluate(CLICKS)
    assert len(before) == 5, before  # the two made as the token went are back
    wait_saved(page, 2)  # and saved
    assert page.evaluate(KEPT) == []
    page.reload()
    wait_shown(page)
    assert page.evaluate(CLICKS) == before
    assert not t.errors, t.errors


def test_two_tabs_on_one_sample_the_second_save_is_told_and_shown_both(live_stack, tab):
    # Issue 38 item 3: the same annotator in two tabs on one sample; before, the last save won silently and a
    # point placed in one tab vanished after a reload. Now the tab saving on an older revision is told, shown both.
    stack, a, page_a, sample = start_saved(live_stack, tab, 2)
    b = tab()
    sign_in_annotator(b, stack)
    assert b.page.evaluate(SAMPLE) == sample  # the drafted sample, restored at revision 1
    place(b.page, 1, 1)
    wait_saved(b.page, 2)
    place(page_a, 0, 3)  # made on revision 1: refused, nothing overwritten
    page_a.wait_for_selector(".lease-banner:not([hidden]) button.keep-mine", timeout=30_000)
    shown = page_a.inner_text(".lease-banner")
    assert "another tab or window" in shown and "There" in shown and "here: 3 points placed" in shown
    assert page_a.get_attribute("body", "data-draft-state") == "conflict"
    page_a.click(".lease-banner button.keep-mine")
    wait_saved(page_a, 3)
    mine = page_a.evaluate(CLICKS)
    page_a.reload()
    wait_shown(page_a)
    assert page_a.evaluate(CLICKS) == mine and len(mine) == 3
    assert not a.errors and not b.errors, (a.errors, b.errors)


def test_take_the_next_task_never_serves_a_stale_prefetched_sample(live_stack, tab):
    # Issue 38 item 4: after a lapsed lease went to someone else, "Take the next task" served the prefetched
    # sample, whose lease had lapsed too and which had gone on to review meanwhile.
    stack, t, page, sample = start_saved(live_stack, tab, 2)
    page.wait_for_function("() => window.__handloop.page.prepared !== null", timeout=30_000)
    ahead = page.evaluate("() => window.__handloop.page.prepared.task.sample_id")
    lapse_lease(stack, sample)
    lapse_lease(stack, ahead)
    with stack.session_factory().begin() as session:  # the prefetched one went on, as if annotated by another
        session.execute(text("UPDATE samples SET state = 'in_review', leased_by_id = NULL, lease_token = NULL, "
                             "lease_expires_at = NULL, lease_kind = NULL WHERE id = :i"), {"i": ahead})
    admin = tab()
    user = stack.users["admin"]
    sign_in(admin, stack.base_url, user.email, user.password, "admin")
    admin.page.goto(stack.base_url + "/#/annotate")
    wait_shown(admin.page)
    assert admin.page.evaluate(SAMPLE) == sample
    place(page, 0, 3)  # refused; the lease cannot be taken again: the banner
    page.click(".lease-banner button.next-task")
    page.wait_for_function(f"() => document.body.dataset.sample !== '{sample}' || "
                           "document.body.dataset.ready === 'annotate-empty'", timeout=30_000)
    shown = page.evaluate("() => window.__handloop.page.task && window.__handloop.page.task.sample_id")
    assert shown not in (sample, ahead), (shown, sample, ahead)
    assert not t.errors and not admin.errors, (t.errors, admin.errors)
