// The work-queue lifecycle the annotate and review pages share (written once here): take the next task
// (POST /api/{queue}/next) or the one prefetched behind it (POST .../prefetch), keep each task's lease alive
// (lease.js), save the work in progress as a draft (drafts.js), send the work with the lease (taken again once
// when it lapsed), hand the sample back, and look again every 10 s while the queue is empty. The page says how
// a task is prepared and shown (its hooks); this controller never touches the page's DOM.
import { paths } from "./api.js";
import { DraftSaver } from "./drafts.js";
import { LeaseKeeper } from "./lease.js";
import { toast } from "./dom.js";

const EMPTY_RETRY_MS = 10000; // the queue was empty: looked at again after this long

/**
 * @typedef {"annotate" | "review"} Queue
 * @typedef {{ sample_id: number, lease_token: string, lease_expires_at: string, [key: string]: any }} Task
 *   a leased task as the server sends it (schemas.tasks)
 * @typedef {{ task: Task, draft?: any, [key: string]: any }} Prepared
 *   what a page prepared for one task (images, proposals or overlay, its draft): shown as one piece
 */

/**
 * What the page does at each step; every hook but prepare and show may be left out.
 * @typedef {object} QueueHooks
 * @property {(task: Task, options: {eager: boolean}) => Promise<Prepared>} prepare
 *   load what the task needs to be shown (eager=false: the task shown next, which may fill in after)
 * @property {(prepared: Prepared) => void} show  put it on screen (the controller's `current` is set already)
 * @property {() => void} [empty]  the queue is empty: say so (the controller looks again in 10 s)
 * @property {(prepared: Prepared) => void} [prefetched]  the task behind the current one is ready
 * @property {(sampleId: number, token: string) => void} [retaken]  the current task's lapsed lease was taken again
 * @property {(sampleId: number, error: Error) => void} [lost]  the current task's sample went to someone else
 * @property {() => any} snapshot  the draft body for the current state, or null (DraftSaver)
 * @property {(state: string, detail?: any) => void} [draftStatus]  DraftSaver's onstatus
 * @property {(theirs: any) => void} [draftConflict]  DraftSaver's onconflict (null: conflicts not offered)
 */

export class QueueController {
  /**
   * @param {import("./api.js").Api} api
   * @param {Queue} queue
   * @param {number} userId  whose work the drafts are
   * @param {QueueHooks} hooks
   */
  constructor(api, queue, userId, hooks) {
    this.api = api;
    this.queue = queue;
    this.hooks = hooks;
    /** @type {Prepared | null} the task on screen */
    this.current = null;
    /** @type {Prepared | null} the task behind it, ready to show */
    this.prepared = null;
    /** @type {Promise<Prepared | null> | null} the prefetch under way (or done) */
    this.preparing = null;
    /** @type {ReturnType<typeof setTimeout> | undefined} */
    this.emptyTimer = undefined;
    this.leases = new LeaseKeeper(api, queue);
    this.leases.onretaken = (sampleId, token) => this.leaseRetaken(sampleId, token);
    this.leases.onlost = (sampleId, error) => this.leaseLost(sampleId, error);
    this.drafts = new DraftSaver(api, queue, { userId, snapshot: hooks.snapshot,
      onstatus: hooks.draftStatus || (() => {}),
      onlease: () => this.current && this.leases.retake(this.current.task.sample_id).catch(() => null),
      onkept: (message) => toast(message, "warn", 15000), onconflict: hooks.draftConflict || null });
  }

  /** The task on screen, or null. */
  get task() {
    return this.current ? this.current.task : null;
  }

  // Whether `sampleId` is the task on screen.
  isCurrent(/** @type {number} */ sampleId) {
    return Boolean(this.current) && this.current.task.sample_id === sampleId;
  }

  async loadNext() {
    clearTimeout(this.emptyTimer);
    let prepared = this.prepared;
    this.prepared = null;
    if (!prepared && this.preparing) prepared = await this.preparing.catch(() => null);
    this.prepared = null;
    // A prefetched sample whose lease lapsed (the laptop slept) may have gone on to someone else and on to the next
    // stage: taken again first, or dropped for a fresh task.
    if (prepared && !(this.leases.expiresAt(prepared.task.sample_id) > Date.now())) {
      const token = await this.leases.retake(prepared.task.sample_id).catch(() => null);
      if (token) prepared.task.lease_token = token;
      else prepared = null;
    }
    if (!prepared) {
      const task = await this.api.post(paths.next(this.queue));
      if (!task) return this.showEmpty();
      prepared = await this.prepareHeld(task, { eager: false });
    }
    this.current = prepared;
    this.hooks.show(prepared);
    this.prefetch();
  }

  /** @returns {Promise<Prepared>} */
  prepareHeld(/** @type {Task} */ task, { eager = true } = {}) {
    this.leases.hold(task);
    return this.hooks.prepare(task, { eager });
  }

  prefetch() {
    const current = this.current.task.sample_id;
    this.preparing = (async () => {
      const task = await this.api.post(paths.prefetch(this.queue), { current_sample_id: current });
      if (!task) return null;
      const prepared = await this.prepareHeld(task);
      if (this.isCurrent(current)) this.prepared = prepared;
      if (this.hooks.prefetched) this.hooks.prefetched(prepared);
      return prepared;
    })().catch((error) => { toast(`prefetch failed: ${error.message}`, "warn"); return null; });
  }

  showEmpty() {
    this.current = null;
    if (this.hooks.empty) this.hooks.empty();
    this.emptyTimer = setTimeout(() => this.loadNext().catch(() => null), EMPTY_RETRY_MS);
  }

  /**
   * POST the work on the current sample with its lease token; when the lease lapsed (or the token is stale:
   * 403 / 409) it is taken again while the sample is free, and the work is sent once more with the new token.
   * @param {string} path
   * @param {{lease_token: string, [key: string]: any}} body  its lease_token is replaced when re-taken
   * @param {number} sampleId
   */
  async postLeased(path, body, sampleId) {
    try {
      return await this.api.post(path, body);
    } catch (error) {
      if (error.status !== 403 && error.status !== 409) throw error;
      body.lease_token = await this.leases.retake(sampleId);
      return this.api.post(path, body);
    }
  }

  // The sample's work went through (submitted, decided, skipped): the server deleted its draft, and its lease
  // is no longer kept (the server ended it).
  finished(/** @type {number} */ sampleId) {
    this.drafts.forget();
    this.leases.drop(sampleId, false);
  }

  /** The time log of a finished sample (POST /api/activity); a failure is only told, never thrown. */
  logActivity(/** @type {object} */ log) {
    this.api.post(paths.activity(), log).catch((error) => toast(`time log not saved: ${error.message}`, "warn"));
  }

  // Give up the sample on screen (it is no longer ours) and show the next.
  async giveUp() {
    if (!this.current) return;
    this.finished(this.current.task.sample_id);
    this.current = null;
    // The prefetched sample's lease lapsed with this one's (the laptop slept): it may have gone on to someone
    // else. Taken again (renewed when still live) before it is shown, else dropped (leaseLost).
    if (this.prepared) {
      const token = await this.leases.retake(this.prepared.task.sample_id).catch(() => null);
      if (token && this.prepared) this.prepared.task.lease_token = token;
      else this.prepared = this.preparing = null; // gone on: a fresh task from the queue
    }
    await this.loadNext();
  }

  leaseRetaken(/** @type {number} */ sampleId, /** @type {string} */ token) {
    if (this.prepared && this.prepared.task.sample_id === sampleId) this.prepared.task.lease_token = token;
    if (!this.isCurrent(sampleId)) return;
    this.current.task.lease_token = token;
    if (this.hooks.retaken) this.hooks.retaken(sampleId, token);
    this.drafts.resume();
  }

  leaseLost(/** @type {number} */ sampleId, /** @type {Error} */ error) {
    if (this.prepared && this.prepared.task.sample_id === sampleId) {
      this.prepared = null; // the prefetched sample went to someone else: fetch another when needed
      return;
    }
    if (this.isCurrent(sampleId) && this.hooks.lost) this.hooks.lost(sampleId, error);
  }

  // The page goes (Back, another page): what is not saved yet is saved now (the next mount restores it); the
  // prefetched sample goes back to the queue; the one on screen stays ours until its lease expires.
  unmount() {
    clearTimeout(this.emptyTimer);
    this.drafts.stop();
    if (this.prepared) this.leases.drop(this.prepared.task.sample_id, true);
    this.leases.dropAll(false);
  }

  // Sign-out: the draft saved under the lease before the lease goes (a new login restores it), every sample back.
  async releaseAll() {
    await this.drafts.settle();
    await this.leases.dropAll(true);
  }
}

// A page that works through a queue (annotate, review): it makes its QueueController in its constructor; what the
// lifecycle's callers read of it (main.js, `bench ui`, the browser tests) is the controller's.
export class QueuePage {
  constructor() {
    /** @type {QueueController} */
    this.queue = null;
  }

  start() {
    return this.queue.loadNext();
  }

  /** @returns {Task | null} the task on screen */
  get task() {
    return this.queue.task;
  }

  /** @returns {Prepared | null} the sample on screen, as the page prepared it */
  get current() {
    return this.queue.current;
  }

  get prepared() {
    return this.queue.prepared;
  }

  get leases() {
    return this.queue.leases;
  }

  get drafts() {
    return this.queue.drafts;
  }

  // Sign-out (main.js): every sample back to the queue, the drafts saved first.
  releaseAll() {
    return this.queue.releaseAll();
  }

  // The data-* attributes of <body> the page published (its publish()), removed as it goes.
  unpublish(/** @type {string[]} */ keys) {
    for (const key of keys) delete document.body.dataset[key];
  }
}
