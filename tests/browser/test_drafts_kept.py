"""Work kept in the tab after a 401 (frontend/js/drafts.js): one entry per queue, user and sample, restored
only onto the server revision it was made on, and the page told when it cannot be. DraftSaver runs in
Chromium against a scripted API (the answers a 401, a 409 or a deleted draft give); the end-to-end 401 case
is in test_drafts.py."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.browser

# A scripted server: drafts[userId][sampleId] = {revision, payload}; refuse = the status every PUT gets (0: none),
# getStatus = the status every GET gets. saver(userId) -> a DraftSaver whose snapshot is state[userId].
HARNESS = """
  const { DraftSaver } = await import('/js/drafts.js');
  sessionStorage.clear();
  const server = { drafts: {}, refuse: 0, getStatus: 0 };
  const state = {}, told = [];
  const fail = (status) => Object.assign(new Error(`HTTP ${status}`), { status });
  const idOf = (url) => Number(url.split('/')[4]);
  const api = (userId) => ({
    get: async (url) => {
      if (server.getStatus) throw fail(server.getStatus);
      return (server.drafts[userId] || {})[idOf(url)] || null;
    },
    fetch: async (method, url, { body }) => {
      if (server.refuse) throw fail(server.refuse);
      const mine = server.drafts[userId] = server.drafts[userId] || {};
      const id = idOf(url), revision = mine[id] ? mine[id].revision + 1 : 1;
      mine[id] = { sample_id: id, revision, payload: body, updated_at: new Date().toISOString() };
      return { json: async () => mine[id] };
    },
  });
  const savers = [];
  const saver = (userId) => {
    const s = new DraftSaver(api(userId), 'annotate', { userId, delayMs: 1e9, snapshot: () => state[userId],
      onkept: (message) => told.push(message) });
    savers.push(s);
    return s;
  };
  // `userId` works on `sampleId` (from server revision `revision`) and the save gets `refuse`.
  const work = async (s, sampleId, revision, clicks, refuse) => {
    s.track(sampleId, revision);
    state[s.userId] = { clicks };
    s.changed();
    server.refuse = refuse;
    await s.flush();
    server.refuse = 0;
  };
  const clicksOf = (draft) => draft && draft.payload.clicks;
  const done = (result) => {
    for (const s of savers) { s.clear(); s.stop(); }
    return result;
  };
"""


def test_a_second_401_on_another_sample_keeps_both(js_page):
    got = js_page(HARNESS + """
      const a = saver(1);
      await work(a, 10, 0, ['on 10'], 401);
      await work(a, 11, 0, ['on 11'], 401);
      const s = saver(1); // signed in again
      return done([clicksOf(await s.load(10)), clicksOf(await s.load(11)), told]);""")
    assert got == [["on 10"], ["on 11"], []]


def test_kept_work_belongs_to_its_user_in_a_shared_tab(js_page):
    got = js_page(HARNESS + """
      const a = saver(1), b = saver(2);
      await work(a, 10, 0, ['a'], 401);
      await work(b, 10, 0, ['b'], 401); // another user, same sample, same tab
      await work(b, 10, 0, ['b again'], 0); // saved: only their kept work goes
      const keys = Object.keys(sessionStorage).sort();
      return done([clicksOf(await saver(1).load(10)), clicksOf(await saver(2).load(10)), keys]);""")
    assert got == [["a"], ["b again"], ["handloop.unsavedDraft.annotate.1.10"]]


def test_kept_work_is_restored_only_onto_the_revision_it_was_made_on(js_page):
    got = js_page(HARNESS + """
      const a = saver(1);
      const out = {};
      // The server's draft still at revision 2: restored.
      server.drafts[1] = { 10: { sample_id: 10, revision: 2, payload: { clicks: ['saved'] } } };
      await work(a, 10, 2, ['saved', 'kept'], 401);
      out.same = clicksOf(await saver(1).load(10));
      // The draft deleted meanwhile (submitted by someone, decided): not restored, and the page is told.
      await work(a, 10, 2, ['saved', 'kept'], 401);
      delete server.drafts[1][10];
      out.gone = await saver(1).load(10);
      out.goneTold = told.splice(0);
      out.goneKept = Object.keys(sessionStorage);
      // The lease not ours any more (409 on reading the draft): the same.
      await work(a, 11, 0, ['on 11'], 401);
      server.getStatus = 409;
      out.taken = await saver(1).load(11);
      server.getStatus = 0;
      out.takenTold = told.splice(0);
      // A newer draft on the server (the keepalive save went through): that one, nothing said.
      server.drafts[1][12] = { sample_id: 12, revision: 3, payload: { clicks: ['newer'] } };
      await work(a, 12, 2, ['older'], 401);
      out.newer = clicksOf(await saver(1).load(12));
      out.newerTold = told.splice(0);
      out.left = Object.keys(sessionStorage);
      return done(out);""")
    assert got["same"] == ["saved", "kept"]
    assert got["gone"] is None and got["goneKept"] == []
    assert len(got["goneTold"]) == 1 and "sample 10" in got["goneTold"][0] and "moved on" in got["goneTold"][0]
    assert got["taken"] is None
    assert len(got["takenTold"]) == 1 and "sample 11" in got["takenTold"][0]
    assert got["newer"] == ["newer"] and got["newerTold"] == []
    assert got["left"] == []


@pytest.fixture
def js_page(browser, static_frontend):
    context = browser.new_context()
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(static_frontend + "/index.html")  # an origin for the module imports; the app itself is not used

    def run(body: str):
        result = page.evaluate(f"async () => {{ {body} }}")
        assert not errors, errors
        return result

    yield run
    context.close()
