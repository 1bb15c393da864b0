// Work in progress saved on the server as it is made (PUT .../draft, debounced), so a reload, another tab,
// the Back button or a new login restores it (backend/services/leases/drafts.py). While a change is not yet
// saved, leaving the page asks first; a page being hidden or unmounted saves at once.
//
// What the server could not take when the page went (the token expired or was revoked: a 401, and the page
// signs out) is kept in this tab's sessionStorage, one entry per queue, user and sample, with the server
// revision it was made on; when that user reads the same sample's draft again (after signing in again) and
// the server's revision is still that one, it is restored and saved. It is dropped once saved, when the
// server holds a newer draft, after a day, or when the sample moved on (its draft deleted or the lease not
// ours: the page is told, onkept).
import { paths } from "./api.js";

// Saves still travelling when a page unmounts (Back, a route change): the next page waits for them before
// it reads the draft, so it never restores an older one.
const inFlight = new Set();
const KEPT_KEY = "handloop.unsavedDraft"; // + `.${queue}.${userId}.${sampleId}`: {revision, payload, keptAt}
const KEPT_MAX_AGE_MS = 24 * 3600 * 1000;

const keptKey = (queue, userId, sampleId) => `${KEPT_KEY}.${queue}.${userId}.${sampleId}`;

// The work of `userId` on `sampleId` the server did not take, or null.
function keptDraft(queue, userId, sampleId) {
  try {
    const kept = JSON.parse(sessionStorage.getItem(keptKey(queue, userId, sampleId)) || "null");
    return kept && Date.now() - kept.keptAt < KEPT_MAX_AGE_MS ? kept : null;
  } catch {
    return null;
  }
}

// Keep `body` (made at `madeAt` on server revision `revision`) unless newer work of the sample is kept.
function keep(queue, userId, sampleId, revision, body, madeAt) {
  const kept = keptDraft(queue, userId, sampleId);
  if (kept && kept.keptAt > madeAt) return;
  const { lease_token: _token, ...payload } = body; // the lease it was made under may be re-taken by then
  try {
    sessionStorage.setItem(keptKey(queue, userId, sampleId), JSON.stringify({ userId, sampleId, revision, payload,
      keptAt: madeAt }));
  } catch {
    // storage full or denied: the server's last draft is what there is
  }
}

// Drop the sample's kept work (only what was kept before `upTo`, the time a save that went through was made).
function dropKept(queue, userId, sampleId, upTo = Infinity) {
  const kept = keptDraft(queue, userId, sampleId);
  if (kept === null || kept.keptAt <= upTo) sessionStorage.removeItem(keptKey(queue, userId, sampleId));
}

export function draftsSettled() {
  return Promise.all([...inFlight].map((p) => p.catch(() => null)));
}

export class DraftSaver {
  // queue: "annotate" | "review"; userId: whose work it is (work kept in the tab is only ever restored to
  // them); snapshot(): the request body for the current state, or null if nothing to save;
  // onstatus(state, detail): "unsaved" | "saving" | "saved" | "error"; onlease(error): a save was refused
  // for the lease (403 / 409), the page re-takes it or tells the user; onkept(message): work kept in this
  // tab could not be restored (the sample moved on), the page says so; onconflict(theirs): another tab or
  // window saved this sample's draft after the revision this page's work was made on (the server refused ours,
  // writing nothing): the page shows both, then calls keepMine() or takeTheirs(theirs).
  /**
   * @param {import("./api.js").Api} api
   * @param {"annotate" | "review"} queue
   * @param {{userId: number, snapshot: () => any, onstatus?: (state: string, detail?: any) => void,
   *   onlease?: (error: any) => void, onkept?: (message: string) => void, onconflict?: ((theirs: any) => void) | null,
   *   delayMs?: number}} options
   */
  constructor(api, queue, { userId, snapshot, onstatus = () => {}, onlease = () => {}, onkept = () => {},
    onconflict = null, delayMs = 700 }) {
    this.api = api;
    this.queue = queue;
    this.userId = userId;
    this.snapshot = snapshot;
    this.onstatus = onstatus;
    this.onlease = onlease;
    this.onkept = onkept;
    this.onconflict = onconflict;
    this.writer = `w${Math.random().toString(36).slice(2, 12)}${Date.now().toString(36)}`; // this page's saves
    this.delayMs = delayMs;
    this.sampleId = null;
    this.dirty = false;
    this.saving = null;
    this.timer = null;
    this.revision = 0;
    this.onBeforeUnload = (e) => {
      if (!this.unsaved) return;
      this.keepHere();
      this.flush({ keepalive: true });
      e.preventDefault();
      e.returnValue = ""; // the browser's own "leave site?" question
    };
    this.onHide = () => { if (document.visibilityState === "hidden" && this.unsaved) this.flush({ keepalive: true }); };
    window.addEventListener("beforeunload", this.onBeforeUnload);
    document.addEventListener("visibilitychange", this.onHide);
  }

  get unsaved() {
    return this.dirty || this.saving !== null;
  }

  url(sampleId = this.sampleId) {
    return paths.draft(this.queue, sampleId);
  }

  // The sample now on screen; changes from here on are saved as its draft.
  track(sampleId, revision = 0) {
    clearTimeout(this.timer);
    this.timer = null;
    this.blocked = false;
    this.sampleId = sampleId;
    this.dirty = false;
    this.revision = revision;
    if (this.keptFor === sampleId) {
      this.keptFor = null;
      this.changed(); // the work restored from this tab goes to the server
    }
  }

  // The caller's draft of a sample, or null (none, or the lease is not theirs: then nothing is restored).
  // Work kept in this tab that the server never got (see above) comes back instead when it was made on the
  // server's current revision.
  async load(sampleId) {
    await draftsSettled();
    let draft;
    try {
      draft = await this.api.get(this.url(sampleId));
    } catch (error) {
      if (error.status !== 403 && error.status !== 409) throw error;
      if (keptDraft(this.queue, this.userId, sampleId)) this.keptLost(sampleId, error.message);
      return null;
    }
    const kept = keptDraft(this.queue, this.userId, sampleId);
    if (kept === null) return draft;
    const revision = draft ? draft.revision : 0;
    if (revision > kept.revision) {
      dropKept(this.queue, this.userId, sampleId); // saved after it was kept (the keepalive save went through)
      return draft;
    }
    if (revision < kept.revision) { // the draft it was made on is gone: submitted, decided or given up
      this.keptLost(sampleId, "its draft was closed meanwhile (submitted, decided or given up)");
      return draft;
    }
    this.keptFor = sampleId; // shown, then saved by track()
    return { sample_id: sampleId, revision, payload: kept.payload, updated_at: new Date(kept.keptAt).toISOString(),
      kept: true };
  }

  keptLost(sampleId, why) {
    dropKept(this.queue, this.userId, sampleId);
    this.onkept(`Your unsaved work on sample ${sampleId} kept in this tab could not be restored: the sample ` +
      `moved on (${why}).`);
  }

  // Keep what is not saved yet in this tab (the server may refuse it: the page is going).
  keepHere() {
    if (this.sampleId === null || !this.unsaved) return; // a save in flight may be cancelled with the page
    const body = this.snapshot();
    if (body) keep(this.queue, this.userId, this.sampleId, this.revision, body, Date.now());
  }

  changed() {
    if (this.sampleId === null) return;
    this.dirty = true;
    this.onstatus("unsaved");
    if (this.retryOnChange) this.blocked = this.retryOnChange = false;
    if (this.blocked) return;
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.flush(), this.delayMs);
  }

  // The lease is ours again (re-taken): save what is pending.
  resume() {
    this.blocked = false;
    if (this.dirty) return this.flush();
    return null;
  }

  // Save now (one save at a time; changes made meanwhile are saved right after).
  async flush({ keepalive = false } = {}) {
    clearTimeout(this.timer);
    this.timer = null;
    if (this.saving && !keepalive) return this.saving; // its finally saves what changed meanwhile
    // The page is going (keepalive): a save in flight is cancelled with it, so the state is sent again.
    if ((!this.dirty && !(keepalive && this.saving)) || this.sampleId === null || this.blocked) return this.saving;
    const snapshot = this.snapshot();
    if (!snapshot) return null;
    const sampleId = this.sampleId;
    const base = this.revision, madeAt = Date.now();
    // The version check (backend/services/leases/drafts.py): only with a page that can show both sides.
    const body = this.onconflict ? { ...snapshot, base_revision: base, writer: this.writer } : snapshot;
    this.dirty = false;
    this.onstatus("saving");
    const request = this.api.fetch("PUT", this.url(sampleId), { body, keepalive })
      .then((response) => response.json())
      .then((draft) => {
        dropKept(this.queue, this.userId, sampleId, madeAt);
        if (this.sampleId === sampleId) {
          this.revision = Math.max(this.revision, draft.revision); // a keepalive resend may answer first
          this.onstatus(this.dirty ? "unsaved" : "saved", draft);
        }
        return draft;
      })
      .catch(async (error) => {
        // Signed out (expired or revoked token): kept here, restored after signing in again.
        if (error.status === 401) keep(this.queue, this.userId, sampleId, base, snapshot, madeAt);
        const theirs = error.status === 409 ? await this.newerElsewhere(sampleId, base) : null;
        if (this.sampleId === sampleId) {
          this.dirty = true; // still to save
          if (theirs) {
            this.blocked = true; // until the person kept one of the two
            this.onstatus("conflict", theirs);
            this.onconflict(theirs);
          } else if (error.status === 403 || error.status === 409) {
            this.onstatus("error", error);
            this.blocked = true; // until the page has the lease again (resume)
            this.onlease(error);
          } else if (!error.status || error.status >= 500) {
            this.onstatus("error", error);
            this.timer = setTimeout(() => this.flush(), Math.max(2000, this.delayMs * 3)); // unreachable: retry
          } else {
            this.onstatus("error", error);
            this.blocked = true; // refused as it is (422, 413): the status names why; the next change retries
            this.retryOnChange = true;
          }
        }
        return null;
      })
      .finally(() => {
        inFlight.delete(request);
        if (this.saving === request) this.saving = null;
        if (this.dirty && this.sampleId === sampleId && this.timer === null && !this.blocked) this.changed();
      });
    inFlight.add(request);
    this.saving = request;
    return request;
  }

  // After a 409: the draft another tab or window saved on top of `base`, or null (the 409 was the lease's).
  async newerElsewhere(sampleId, base) {
    try {
      const draft = await this.api.get(this.url(sampleId));
      return draft && draft.revision !== base && draft.payload.writer !== this.writer ? draft : null;
    } catch {
      return null;
    }
  }

  // The person keeps this page's work over the other save they were shown: saved on top of it.
  keepMine(theirs) {
    this.revision = theirs.revision;
    this.blocked = false;
    this.dirty = true;
    return this.flush();
  }

  // The person takes the other save (the page shows it): this page goes on from its revision.
  takeTheirs(theirs) {
    this.revision = theirs.revision;
    this.blocked = false;
    this.dirty = false;
    this.onstatus("saved", theirs);
  }

  // Save until nothing is pending (or a save is refused); for signing out, before the lease is released.
  async settle() {
    for (let i = 0; i < 5 && this.unsaved && !this.blocked; i++) {
      clearTimeout(this.timer);
      this.timer = null;
      await (this.saving || this.flush());
    }
  }

  // The sample was submitted (the server deleted its draft) or given up: nothing more to save for it.
  forget() {
    if (this.sampleId !== null) dropKept(this.queue, this.userId, this.sampleId);
    this.clear();
  }

  clear() {
    clearTimeout(this.timer);
    this.timer = null;
    this.dirty = false;
    this.sampleId = null;
  }

  // The page goes: what is not saved is kept in the tab and sent (the request outlives the page).
  stop() {
    this.keepHere();
    if (this.unsaved) this.flush({ keepalive: true });
    window.removeEventListener("beforeunload", this.onBeforeUnload);
    document.removeEventListener("visibilitychange", this.onHide);
    this.clear();
  }
}
