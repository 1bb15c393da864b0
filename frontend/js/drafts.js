// Work in progress saved on the server as it is made (PUT .../draft, debounced), so a reload, another tab,
// the Back button or a new login restores it (backend/services/drafts.py). While a change is not yet
// saved, leaving the page asks first; a page being hidden or unmounted saves at once.

// Saves still travelling when a page unmounts (Back, a route change): the next page waits for them before
// it reads the draft, so it never restores an older one.
const inFlight = new Set();

export function draftsSettled() {
  return Promise.all([...inFlight].map((p) => p.catch(() => null)));
}

export class DraftSaver {
  // queue: "annotate" | "review"; snapshot(): the request body for the current state, or null if nothing
  // to save; onstatus(state, detail): "unsaved" | "saving" | "saved" | "error"; onlease(error): a save
  // was refused for the lease (403 / 409), the page re-takes it or tells the user.
  constructor(api, queue, { snapshot, onstatus = () => {}, onlease = () => {}, delayMs = 700 }) {
    this.api = api;
    this.queue = queue;
    this.snapshot = snapshot;
    this.onstatus = onstatus;
    this.onlease = onlease;
    this.delayMs = delayMs;
    this.sampleId = null;
    this.dirty = false;
    this.saving = null;
    this.timer = null;
    this.revision = 0;
    this.onBeforeUnload = (e) => {
      if (!this.unsaved) return;
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
    return `/api/${this.queue}/samples/${sampleId}/draft`;
  }

  // The sample now on screen; changes from here on are saved as its draft.
  track(sampleId, revision = 0) {
    clearTimeout(this.timer);
    this.timer = null;
    this.blocked = false;
    this.sampleId = sampleId;
    this.dirty = false;
    this.revision = revision;
  }

  // The caller's draft of a sample, or null (none, or the lease is not theirs: then nothing is restored).
  async load(sampleId) {
    await draftsSettled();
    try {
      return await this.api.get(this.url(sampleId));
    } catch (error) {
      if (error.status === 403 || error.status === 409) return null;
      throw error;
    }
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
    if (!this.dirty || this.sampleId === null || this.blocked) return this.saving;
    const body = this.snapshot();
    if (!body) return null;
    const sampleId = this.sampleId;
    this.dirty = false;
    this.onstatus("saving");
    const request = this.api.fetch("PUT", this.url(sampleId), { body, keepalive })
      .then((response) => response.json())
      .then((draft) => {
        if (this.sampleId === sampleId) {
          this.revision = draft.revision;
          this.onstatus(this.dirty ? "unsaved" : "saved", draft);
        }
        return draft;
      })
      .catch((error) => {
        if (this.sampleId === sampleId) {
          this.dirty = true; // still to save
          this.onstatus("error", error);
          if (error.status === 403 || error.status === 409) {
            this.blocked = true; // until the page has the lease again (resume)
            this.onlease(error);
          } else if (!error.status || error.status >= 500) {
            this.timer = setTimeout(() => this.flush(), Math.max(2000, this.delayMs * 3)); // unreachable: retry
          } else {
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
    clearTimeout(this.timer);
    this.timer = null;
    this.dirty = false;
    this.sampleId = null;
  }

  stop() {
    if (this.unsaved) this.flush({ keepalive: true });
    window.removeEventListener("beforeunload", this.onBeforeUnload);
    document.removeEventListener("visibilitychange", this.onHide);
    this.forget();
  }
}
