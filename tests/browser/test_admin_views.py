"""The admin page does not mislead: a round cannot be launched below the minimum of accepted labels (the
button says why in plain words, the API refuses with 409 and writes nothing); leased samples are counted
apart from free ones; jobs show their sample, when their attempt started, how long it took (not the wait
in the queue) and how they ended."""

from __future__ import annotations

from datetime import timedelta

import pytest

from backend.db.base import utcnow
from backend.models.enums import JobKind, JobState
from backend.services.jobs import jobs
from backend.services.jobs.jobs import InMemoryJobQueue
from tests.browser.conftest import sign_in

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_the_launch_button_says_why_not_and_the_counts_show_leases(live_stack, tab):
    stack = live_stack(worker=False, round_min_training_samples=2)
    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()  # one sample on an annotator's screen
    finished, waiting = _two_jobs(stack, task["sample_id"])
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
    assert headers[:6] == ["id", "kind", "sample", "state", "started", "took"], headers
    done_row = f'#jobs tr[data-job="{finished}"]'
    assert page.inner_text(f"{done_row} td.took") == "12.0 s"  # the attempt, not the 5 minutes in the queue
    assert page.inner_text(f"{done_row} td.sample") == str(task["sample_id"])
    assert page.inner_text(f'#jobs tr[data-job="{waiting}"] td.sample') == "–"
    assert ":" in page.inner_text(f"{done_row} td.started")
    assert page.inner_text(f"{done_row} td.msg") == "done"  # not its last progress message
    assert page.inner_text(f'#jobs tr[data-job="{waiting}"] td.started').startswith("waiting since")
    assert page.inner_text(f'#jobs tr[data-job="{waiting}"] td.took') == "–"
    with stack.client("admin") as http:
        refused = http.post("/api/admin/rounds", json={"note": "too early"})
        assert refused.status_code == 409 and "at least 2 needed" in refused.json()["detail"]
        assert http.get("/api/admin/rounds").json() == []  # nothing written: no round completed, none opened
    t.shot("admin-launch-refused")
    assert task["sequence"] == "seq000"
    assert not t.errors, t.errors


def _two_jobs(stack, sample_id: int) -> tuple[int, int]:
    """A job of `sample_id` that waited 5 minutes, ran 12 s and succeeded after reporting "predicting 0/16",
    and a job of no sample that no worker has started."""
    factory = stack.session_factory()
    with factory() as session, session.begin():
        done = jobs.create(session, InMemoryJobQueue(), JobKind.predict, sample_id=sample_id, payload={})
        waiting = jobs.create(session, InMemoryJobQueue(), JobKind.predict, payload={})
    with factory() as session, session.begin():
        jobs.claim(session, done.id, "w1:1", stale_after_s=60)
        jobs.update_progress(session, done.id, 0.0, "predicting 0/16")
        jobs.finish(session, done.id, JobState.succeeded)
    with factory() as session, session.begin():  # as if it had waited 5 minutes and then run 12 s
        job, start = jobs.get(session, done.id), utcnow() - timedelta(seconds=60)
        job.created_at, job.started_at, job.finished_at = start - timedelta(seconds=300), start, start + \
            timedelta(seconds=12)
    return done.id, waiting.id


def test_the_round_progress_bar_follows_its_phases_live(live_stack, tab):
    # The round's bar moves with its phases as the workers report (training by the elapsed share of its
    # budget), on the open page, and a finished round keeps no phase message.
    from backend.services.rounds import rounds
    from workers.tasks import round_progress
    from workers.tasks.context import build_context
    from workers.tasks.round_steps import start_round

    stack = live_stack(worker=False, round_handsegnet_budget_s=90.0, round_mvnet_budget_s=240.0)
    factory = stack.session_factory()
    with factory() as session, session.begin():  # launched by the service: this capture has no accepted labels
        _, job = rounds.launch(session, InMemoryJobQueue(), None, None, None, "live bar", min_training_samples=0)
        round_job_id = job.id
    ctx = build_context(stack.settings, job_queue=InMemoryJobQueue())
    train = dict(zip(("handsegnet", "mvnet"), start_round(ctx, round_job_id), strict=True))

    def report(net: str, fraction: float) -> None:
        with ctx.session_factory.begin() as session:
            if fraction >= 1:
                jobs.finish(session, train[net], JobState.succeeded)
            else:
                jobs.update_progress(session, train[net], fraction, "training")
            round_progress.refresh(session, round_job_id, stack.settings)

    report("handsegnet", 0.5)
    t = tab()
    user = stack.users["admin"]
    sign_in(t, stack.base_url, user.email, user.password, "admin")
    page = t.page
    live = f'.round-progress .live[data-job="{round_job_id}"]'
    page.wait_for_selector(f"{live} .phase.running")
    assert "train HandSegNet (45 of 90 s)" in page.inner_text(f"{live} .live-head")
    first = int(page.get_attribute(f"{live} [role=progressbar]", "aria-valuenow"))
    report("handsegnet", 1.0)
    report("mvnet", 0.5)  # while the page is open
    page.wait_for_function("""(sel) => { const el = document.querySelector(sel);
        return el && el.textContent.includes("train MVNet (120 of 240 s)"); }""", arg=f"{live} .live-head")
    now = int(page.get_attribute(f"{live} [role=progressbar]", "aria-valuenow"))
    states = page.eval_on_selector_all(f"{live} .phase", "els => els.map((e) => [e.textContent, e.dataset.state])")
    assert [s for _, s in states] == ["done", "running", "pending", "pending", "pending"], states
    assert states[0][0].startswith("train HandSegNet") and states[1][0].startswith("train MVNet"), states
    assert first < now and now >= 50, (first, now)  # training is most of the round: most of the bar
    t.shot("admin-round-phases")
    with ctx.session_factory.begin() as session:
        jobs.finish(session, round_job_id, JobState.succeeded)
    page.wait_for_selector(f'{live}[data-state="succeeded"]')
    assert "train MVNet" not in page.inner_text(f"{live} .live-head")  # no stale phase message
    ctx.session_factory.kw["bind"].dispose()
    assert not t.errors, t.errors


def test_a_failed_round_shows_why_and_the_round_before_it_open_again(live_stack, tab):
    from backend.services.rounds import rounds

    stack = live_stack(worker=False)
    factory = stack.session_factory()
    with factory() as session, session.begin():
        _, job = rounds.launch(session, InMemoryJobQueue(), None, None, None, "", min_training_samples=0)
    with factory() as session, session.begin():  # as a worker reports a training that failed
        jobs.finish(session, job.id, JobState.failed, error="training mvnet: 1 accepted samples; a round needs 2")
    t = tab()
    user = stack.users["admin"]
    sign_in(t, stack.base_url, user.email, user.password, "admin")
    page = t.page
    states = page.eval_on_selector_all(".rounds-table tbody tr", "rows => rows.map((r) => [r.dataset.round, "
                                       "r.querySelector('.round-state').firstChild.textContent])")
    assert states == [["0", "running"], ["1", "failed"]], states
    assert "a round needs 2" in page.inner_text('.rounds-table tr[data-round="1"] .round-failure')
    assert page.inner_text("button.launch-round").startswith("Complete D₀")  # D_0 is the open round again
    t.shot("admin-round-failed")
    assert not t.errors, t.errors


def test_one_round_at_a_time_and_a_cancelled_round_leaves_no_row(live_stack, tab):
    # Issue 38 item 5: "Complete D1 and launch the next round" stayed enabled while D1's job trained (clicking it
    # completed D1 with no models and queued round 2); a cancelled round left a "D2 cancelled" row and column.
    from backend.services.rounds import rounds

    stack = live_stack(worker=False)
    with stack.session_factory()() as session, session.begin():
        _, job = rounds.launch(session, InMemoryJobQueue(), None, None, None, "", min_training_samples=0)
    t = tab()
    user = stack.users["admin"]
    sign_in(t, stack.base_url, user.email, user.password, "admin")
    page = t.page
    page.wait_for_selector(f'.round-progress .live[data-job="{job.id}"]')  # the panel follows the running job
    assert page.inner_text("button.launch-round").startswith("Complete D₁")
    assert page.is_disabled("button.launch-round")
    assert "one round at a time" in page.inner_text(".launch-why")
    with stack.client("admin") as http:
        refused = http.post("/api/admin/rounds", json={"note": "while D1 trains"})
        assert refused.status_code == 409 and "one round at a time" in refused.json()["detail"]
    page.on("dialog", lambda dialog: dialog.accept())
    page.click('.rounds-table tr[data-round="1"] button.danger')
    page.wait_for_function("() => document.querySelectorAll('.rounds-table tbody tr').length === 1")
    states = page.eval_on_selector_all(".rounds-table tbody tr", "rows => rows.map((r) => [r.dataset.round, "
                                       "r.querySelector('.round-state').firstChild.textContent])")
    assert states == [["0", "running"]], states
    assert "D₁" not in page.inner_text("#charts")  # no column for the cancelled round
    assert page.inner_text("button.launch-round").startswith("Complete D₀")
    assert "one round at a time" not in page.inner_text("#rounds")  # only the labels still missing, if any
    assert not t.errors, t.errors
