"""The queue lifecycle the annotate and review pages share (frontend/js/queue.js), run in Chromium against a
fake API that records each call: the work sent with its lease is retried once with the lease taken again, the
prefetched task is shown next without asking the queue, a prefetched task whose lease lapsed is taken again or
dropped for a fresh one, and an empty queue is said so."""

from __future__ import annotations

import pytest

from tests.browser.test_js_logic import js  # noqa: F401  (the fixture: a page with the modules' origin)

pytestmark = pytest.mark.browser

# A fake Api: post(path, body) answers from arg.answers[path] (a list, first answer first; an answer with
# `status` is thrown as the server's refusal), and every call is recorded as [path, body].
SETUP = """
const { QueueController } = await import('/js/queue.js');
const calls = [], shown = [], events = [];
const answers = JSON.parse(JSON.stringify(arg.answers));
const api = {
  async post(path, body) {
    calls.push([path, body === undefined ? null : JSON.parse(JSON.stringify(body))]);
    const queue = answers[path] || [];
    const answer = queue.length ? queue.shift() : null;
    if (answer && answer.status) throw Object.assign(new Error(answer.detail || 'refused'), answer);
    return answer;
  },
  async get() { return null; },
};
const hooks = {
  prepare: async (task) => ({ task }),
  show: (prepared) => shown.push(prepared.task.sample_id),
  empty: () => events.push('empty'),
  lost: (sampleId) => events.push(`lost ${sampleId}`),
  snapshot: () => null,
};
const queue = new QueueController(api, 'annotate', 1, hooks);
"""
FUTURE = "2999-01-01T00:00:00Z"
PAST = "2000-01-01T00:00:00Z"


def _task(sample_id: int, token: str = "t", expires: str = FUTURE) -> dict:
    return {"sample_id": sample_id, "lease_token": token, "lease_expires_at": expires}


def test_work_is_sent_again_once_with_the_lease_taken_again(js):  # noqa: F811
    got = js(SETUP + """
      const sent = await queue.postLeased('/submit', { lease_token: 'old', clicks: [] }, 7).catch((e) => e.status);
      queue.leases.hold({ sample_id: 7, lease_token: 'old', lease_expires_at: arg.future });
      const retried = await queue.postLeased('/submit', { lease_token: 'old', clicks: [] }, 7);
      const failed = await queue.postLeased('/broken', { lease_token: 'new' }, 7).catch((e) => e.status);
      queue.unmount();
      return { sent, retried, failed, calls };""",
             {"future": FUTURE, "answers": {
                 "/submit": [{"status": 409}, {"status": 409}, {"id": 3}],
                 "/api/annotate/samples/7/lease/retake": [{"lease_token": "new", "lease_expires_at": FUTURE}],
                 "/broken": [{"status": 500}]}})
    # Without a lease kept for the sample there is nothing to take again: the refusal stands.
    assert got["sent"] is None  # no status: the page is told the lease is not kept, no request made
    assert got["retried"] == {"id": 3}
    assert got["failed"] == 500  # not a lease problem: no retake, the error goes to the page
    paths = [path for path, _ in got["calls"]]
    assert paths == ["/submit", "/submit", "/api/annotate/samples/7/lease/retake", "/submit", "/broken"]
    assert got["calls"][3][1]["lease_token"] == "new"  # the work sent again under the new token


def test_the_prefetched_task_is_shown_next_and_an_empty_queue_is_said(js):  # noqa: F811
    got = js(SETUP + """
      await queue.loadNext();
      await queue.preparing;
      const after_first = [...shown];
      await queue.loadNext();  // the prefetched one: the queue is not asked
      await queue.preparing;
      await queue.loadNext();  // nothing prefetched, the queue empty
      const current = queue.current;
      queue.unmount();
      return { after_first, shown, events, current, calls: calls.map(([p]) => p) };""",
             {"answers": {"/api/annotate/next": [_task(1), None],
                          "/api/annotate/prefetch": [_task(2), None]}})
    assert got["after_first"] == [1]
    assert got["shown"] == [1, 2]
    assert got["events"] == ["empty"] and got["current"] is None
    assert got["calls"] == ["/api/annotate/next", "/api/annotate/prefetch", "/api/annotate/prefetch",
                            "/api/annotate/next"]


@pytest.mark.parametrize("still_free", [True, False])
def test_a_prefetched_task_whose_lease_lapsed_is_taken_again_or_dropped(js, still_free):  # noqa: F811
    retake = {"lease_token": "t2", "lease_expires_at": FUTURE} if still_free else {"status": 409}
    got = js(SETUP + """
      await queue.loadNext();
      await queue.preparing;
      await queue.loadNext();
      const token = queue.current.task.lease_token;
      queue.unmount();
      return { shown, events, token, calls: calls.map(([p]) => p) };""",
             {"answers": {"/api/annotate/next": [_task(1), _task(3)],
                          "/api/annotate/prefetch": [_task(2, expires=PAST), None],
                          "/api/annotate/samples/2/lease/retake": [retake]}})
    assert got["calls"][:3] == ["/api/annotate/next", "/api/annotate/prefetch",
                                "/api/annotate/samples/2/lease/retake"]
    if still_free:
        assert got["shown"] == [1, 2] and got["token"] == "t2"
    else:  # it went on to someone else: a fresh task from the queue instead (the lost prefetch tells no one)
        assert got["shown"] == [1, 3] and got["calls"][3] == "/api/annotate/next" and got["events"] == []
