// The annotate page: 8 views in a grid plus one enlarged with zoom and pan; click wrist and fingertips
// per view (keys pick the keypoint, mark it occluded or not annotated), accept or drag proposals, correct
// the automatic mask with brush and eraser, undo and redo, submit; the next task is prefetched.
import { Annotation, inside, proposals as computeProposals, triangulateClicked } from "./annotation.js";
import { fitCanvas, fmt, h, handSide, isTyping, toast, fill } from "./dom.js";
import { epipolarCurve, projectPoint } from "./geometry.js";
import { marker, segment } from "./draw.js";
import { History } from "./history.js";
import { DraftSaver } from "./drafts.js";
import { decodeMask, loadFullImage, loadView, needsFullImage } from "./images.js";
import { colorOf, SPARSE, SPARSE_LABELS } from "./keypoints.js";
import { LeaseKeeper } from "./lease.js";
import { MaskLayer, MaskOverlay, StrokeRecorder, unionRect } from "./mask.js";
import { ActionTimer } from "./timing.js";
import { Viewport } from "./viewport.js";
import { paths } from "./api.js";

const HIT_PX = 12; // how close (screen px) a press must be to grab a point
const LOUPE_R = 56; // the magnifier's radius, screen px
const LOUPE_OFFSET = 80; // its centre from the cursor, screen px (up and right, flipped near the edges)
const LOUPE_ZOOM = 4; // times the view's zoom ...
const LOUPE_MAX_PX = 24; // ... up to this many screen px per image pixel
const DRAG_PX = 3; // movement below this is a click, not a drag
// A view opens on the hand with the working copy's pixels at most this many screen px wide (more is visibly
// blocky; zooming in further loads the full-resolution pixels), unless the whole image already shows larger.
const OPEN_MAX_PX = 2;
const MIN_CONF = 0.3; // a source's points below this confidence are not offered (annotation.js proposals())
const ALTERNATE_PX = 2; // a detector point this close to the proposal shown is not drawn again
const SOURCE_LETTER = { triangulated: "T", fit: "F", mvnet: "M", detector: "D" };
// Enter accepts only proposals at least this confident; the others are ringed orange for a look (A takes
// one anyway). A fit's projection has no confidence: it is always left for a look.
const ACCEPT_CONF = 0.6;
const HELP = [
  ["1 … 6", "pick wrist, thumb, index, middle, ring, pinky"],
  ["click", "place the keypoint (then the next one is picked); the magnifier beside the cursor shows where"],
  ["drag", "move a point or a proposal"],
  ["A / Enter", `accept the proposal of this keypoint / all of this view's with confidence >= ${ACCEPT_CONF}; ` +
    "those the fit's mesh hides (\"hidden\") as occluded"],
  ["O", "toggle occluded: the point just placed in this view, else the picked one (ringed white)"],
  ["N", "not annotated in this view: the point just placed, else the picked one"],
  ["Del / Backspace", "clear the picked keypoint in this view"],
  ["Tab / Shift+Tab", "next / previous view (or click a thumbnail)"],
  ["M", "mask mode on / off; B brush, E eraser"],
  ["[ ] / wheel", "brush size (wheel in mask mode; Ctrl+wheel zooms)"],
  ["P", "back to points"],
  ["wheel, right-drag", "zoom, pan (Space+drag pans too)"],
  ["+ / - / 0", "zoom in / out at the centre / fit the hand (again: the whole image); each view keeps its zoom"],
  ["H", "hide / show the mask"],
  ["Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y", "undo / redo / redo"],
  ["X", "no hand in this view: every point here not annotated (again: undo the mark)"],
  ["Ctrl+Enter", "submit and show the next task (asks first when points are not set; again: submit as is)"],
  ["Esc", "cancel a drag, give the keys back to the view (from any button)"],
  ["?", "open / close this list"],
];

export async function mountAnnotate(root, ctx) {
  const page = new AnnotatePage(root, ctx);
  await page.start();
  return page;
}

class AnnotatePage {
  constructor(root, { api, user }) {
    this.api = api;
    this.root = root;
    this.leases = new LeaseKeeper(api, "annotate");
    this.leases.onretaken = (sampleId, token) => this.leaseRetaken(sampleId, token);
    this.leases.onlost = (sampleId, error) => this.leaseLost(sampleId, error);
    this.drafts = new DraftSaver(api, "annotate", { userId: user.id, snapshot: () => this.draftBody(),
      onstatus: (state, detail) => this.draftStatus(state, detail),
      onlease: () => this.task && this.leases.retake(this.task.sample_id).catch(() => null),
      onkept: (message) => toast(message, "warn", 15000), onconflict: (theirs) => this.draftConflict(theirs) });
    this.history = new History();
    this.history.onchange = () => this.renderSide();
    this.vp = new Viewport();
    this.mode = "points";
    this.tool = "brush";
    this.radius = 12;
    this.showMask = true;
    this.autoAdvance = true;
    this.prepared = null;
    this.preparing = null;
    this.pending = 0;
    this.keys = new Set();
    this.zooms = new Map(); // "sample/view" -> {scale, ox, oy, minScale}: each view keeps its zoom and pan
    this.metrics = { shown: [] };
    this.failedFits = []; // the fits that failed on this person's submissions (GET /api/annotate/fit-failures)
    this.noHand = new Set();
    this.build();
    this.onKey = (e) => this.keydown(e);
    this.onKeyUp = (e) => this.keys.delete(e.code);
    this.onResize = () => { this.fitView(); this.requestRender(); };
    // The clock counts working time: between inputs, not across a pause of more than 30 s or a hidden tab.
    this.onVisibility = () => { if (document.hidden && this.timer) this.timer.pause(); };
    document.addEventListener("visibilitychange", this.onVisibility);
    window.addEventListener("keydown", this.onKey);
    window.addEventListener("keyup", this.onKeyUp);
    window.addEventListener("resize", this.onResize);
    this.clock = setInterval(() => this.renderClock(), 1000);
  }

  build() {
    this.canvas = h("canvas", { class: "main-canvas", "aria-label": "enlarged view", tabindex: "0" });
    this.thumbs = h("div", { class: "thumbs", "aria-label": "views" });
    this.hud = h("div", { class: "hud" });
    this.banner = h("div", { class: "lease-banner", role: "alert", hidden: true });
    // A question before an action that loses or gives up something (an incomplete submit, a skip): in the page,
    // answered by its buttons or keys (Ctrl+Enter again / Esc).
    this.ask = h("div", { class: "lease-banner ask", role: "alertdialog", hidden: true });
    this.side = h("aside", { class: "side" });
    this.root.append(h("div", { class: "annotate-page" }, this.thumbs,
      h("section", { class: "stage" }, this.canvas, this.hud, this.banner, this.ask), this.side));
    const c = this.canvas;
    c.addEventListener("pointerdown", (e) => this.pointerdown(e));
    c.addEventListener("pointermove", (e) => this.pointermove(e));
    c.addEventListener("pointerup", (e) => this.pointerup(e));
    c.addEventListener("pointercancel", (e) => this.pointerup(e));
    c.addEventListener("pointerleave", () => { this.hover = null; this.requestRender(); });
    c.addEventListener("wheel", (e) => this.wheel(e), { passive: false });
    c.addEventListener("contextmenu", (e) => e.preventDefault());
  }

  async start() {
    await this.loadNext();
  }

  unmount() {
    window.removeEventListener("keydown", this.onKey);
    window.removeEventListener("keyup", this.onKeyUp);
    window.removeEventListener("resize", this.onResize);
    document.removeEventListener("visibilitychange", this.onVisibility);
    clearInterval(this.clock);
    clearTimeout(this.emptyTimer);
    clearTimeout(this.fitWatch);
    this.drafts.stop(); // what is not saved yet goes now (Back, another page): the next mount restores it
    // The prefetched sample goes back to the queue; the one on screen stays ours until its lease expires.
    if (this.prepared) this.leases.drop(this.prepared.task.sample_id, true);
    this.leases.dropAll(false);
  }

  async releaseAll() {
    await this.drafts.settle(); // saved under the lease before the lease goes: a new login restores it
    await this.leases.dropAll(true);
  }

  // --- tasks --------------------------------------------------------------------------------------

  // A task's proposals and images. The task shown next (eager=false) is ready as soon as its first view
  // is: the others fill in while the annotator works on it. A prefetched task is loaded whole.
  async prepare(task, { eager = true } = {}) {
    const t0 = performance.now();
    this.leases.hold(task);
    const loads = task.views.map((view) => loadView(this.api, view));
    const proposals = this.api.get(paths.proposals(task.sample_id));
    const draft = this.drafts.load(task.sample_id);
    const ready = eager ? await Promise.all(loads) : [await loads[0]];
    const views = task.views.map((view, i) => ({ ...view, image: null, maskImage: null, ...(ready[i] || {}) }));
    return { task, proposals: await proposals, draft: await draft, views, loads, loadMs: performance.now() - t0 };
  }

  async loadNext() {
    let prepared = null;
    if (this.prepared) {
      prepared = this.prepared;
      this.prepared = null;
    } else if (this.preparing) {
      prepared = await this.preparing.catch(() => null);
      this.prepared = null;
    }
    // A prefetched sample whose lease lapsed (the laptop slept) may have gone on to someone else and on to review:
    // taken again first, or dropped for a fresh task.
    if (prepared && !(this.leases.expiresAt(prepared.task.sample_id) > Date.now())) {
      const token = await this.leases.retake(prepared.task.sample_id).catch(() => null);
      if (token) prepared.task.lease_token = token;
      else prepared = null;
    }
    if (!prepared) {
      const task = await this.api.post(paths.next("annotate"));
      if (!task) return this.showEmpty();
      prepared = await this.prepare(task, { eager: false });
    }
    this.show(prepared);
    this.prefetch();
  }

  prefetch() {
    const current = this.task.sample_id;
    this.preparing = (async () => {
      const task = await this.api.post(paths.prefetch("annotate"), { current_sample_id: current });
      if (!task) return null;
      const prepared = await this.prepare(task);
      if (this.task && this.task.sample_id === current) this.prepared = prepared;
      return prepared;
    })().catch((error) => { toast(`prefetch failed: ${error.message}`, "warn"); return null; });
  }

  showEmpty() {
    this.task = null;
    this.root.querySelector(".annotate-page").classList.add("empty");
    fill(this.side, h("div", { class: "empty-note" }, h("h2", {}, "Nothing to annotate"),
      h("p", {}, "The annotation queue is empty. This page looks again every 10 s."),
      h("button", { onclick: () => this.loadNext() }, "Look again")));
    fill(this.thumbs, );
    this.hud.textContent = "";
    const ctx = this.canvas.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, this.canvas.width, this.canvas.height);
    document.body.dataset.ready = "annotate-empty";
    this.emptyTimer = setTimeout(() => this.loadNext().catch(() => null), 10000);
  }

  show(prepared) {
    const t0 = performance.now();
    this.root.querySelector(".annotate-page").classList.remove("empty");
    const { task, proposals, views } = prepared;
    this.task = task;
    this.sources = proposals.sources;
    this.reviewNote = proposals.review_note;
    this.fitFailure = proposals.fit_failure || null;
    this.noHand = new Set(); // views marked "no hand here"
    this.closeAsk();
    this.cameras = new Map(proposals.cameras.map((c) => [c.view_id, c]));
    this.views = views.map((v) => ({ ...v, mask: null, overlay: null, maskEdited: false }));
    this.decodeMask(this.views[0]);
    this.views.forEach((view, i) => {
      if (view.image) return;
      prepared.loads[i].then((loaded) => {
        if (this.task !== task) return;
        Object.assign(view, loaded);
        this.decodeMask(view);
        if (i === this.viewIndex) this.requestRender();
        this.renderThumb(i);
      }).catch((error) => toast(`view ${view.camera} did not load: ${error.message}`, "error"));
    });
    this.annotation = new Annotation(this.views.map((v) => v.id), task.keypoints_to_click || SPARSE);
    // The points placed before (a sample back from review or a failed fit); "not annotated" ones stay unset, to
    // be decided again: a failed empty submission must not come back as every point done.
    for (const c of proposals.previous_clicks) {
      if (c.x === null || c.x === undefined) continue;
      if (this.annotation.clicks.has(c.view_id) && this.annotation.keypoints.includes(c.keypoint)) {
        this.previousClicks = true;
        this.annotation.set(c.view_id, c.keypoint, { x: c.x, y: c.y, visibility: c.visibility });
      }
    }
    this.viewIndex = 0;
    this.keypoint = this.annotation.firstUnset(this.views[0].id) ?? SPARSE[0];
    this.timer = new ActionTimer({ dropIdle: true });
    this.submissionId = crypto.randomUUID();
    this.hideBanner();
    this.justPlaced = null; // a view of the previous sample
    delete document.body.dataset.draftState;
    delete document.body.dataset.draftSaved;
    delete document.body.dataset.draftLeftBy;
    this.drafts.track(task.sample_id, prepared.draft ? prepared.draft.revision : 0);
    if (prepared.draft) this.applyDraft(prepared.draft);
    this.updateProposals();
    this.history.clear();
    this.buildThumbs();
    this.fitView();
    this.renderNow(true);
    this.renderSide();
    this.metrics.shown.push({ sample_id: task.sample_id, show_ms: performance.now() - t0, load_ms: prepared.loadMs,
      at_ms: performance.now() });
    this.decodeRestLater(task.sample_id);
    document.body.dataset.draft = prepared.draft ? String(prepared.draft.revision) : "none";
    document.body.dataset.ready = "annotate";
    document.body.dataset.sample = String(task.sample_id);
  }

  get view() {
    return this.views[this.viewIndex];
  }

  // --- editing ------------------------------------------------------------------------------------

  setClick(viewId, keypoint, value, kind) {
    const changes = [{ viewId, keypoint, value, previous: this.annotation.set(viewId, keypoint, value) }];
    // A point placed by hand moves the proposals accepted for this keypoint in the other views with it.
    if (value && !value.from && (kind === "click" || kind === "drag")) {
      for (const c of this.reprojections(keypoint, viewId)) {
        changes.push({ ...c, previous: this.annotation.set(c.viewId, c.keypoint, c.value) });
      }
    }
    // O and N then apply to this point, even after the selection moved on to the next keypoint.
    if (kind === "click" || kind === "accept" || kind === "drag") this.justPlaced = value ? { viewId, keypoint } : null;
    const apply = (which) => {
      for (const c of changes) this.annotation.set(c.viewId, c.keypoint, c[which]);
      for (const c of changes) this.changed(c.viewId);
    };
    this.history.record({ kind, undo: () => apply("previous"), redo: () => apply("value") });
    this.timer.mark(kind, { view_id: viewId, keypoint, ...(changes.length > 1 ? { reprojected: changes.length - 1 } : {}) });
    for (const c of changes) this.changed(c.viewId);
  }

  // The keypoint re-triangulated from the views where it was placed by hand, projected into the views
  // where it was accepted from a proposal: [{viewId, keypoint, value}] for those that move.
  reprojections(keypoint, exceptViewId) {
    const tri = triangulateClicked(this.annotation, this.cameras, keypoint);
    if (!tri) return [];
    const out = [];
    for (const viewId of this.annotation.viewIds) {
      const c = this.annotation.get(viewId, keypoint);
      if (viewId === exceptViewId || !c || !c.from || c.x === null) continue;
      const cam = this.cameras.get(viewId);
      const p = projectPoint(tri.point, cam);
      if (!inside(p, cam) || Math.hypot(p[0] - c.x, p[1] - c.y) < 0.01) continue;
      out.push({ viewId, keypoint, value: { ...c, x: p[0], y: p[1], from: "triangulated", confidence: tri.confidence } });
    }
    return out;
  }

  changed(viewId) {
    this.drafts.changed();
    this.updateProposals();
    this.renderThumb(this.views.findIndex((v) => v.id === viewId));
    this.requestRender();
    this.renderSide();
  }

  updateProposals() {
    this.proposals = computeProposals(this.annotation, this.cameras, this.sources);
    this.alternates = this.detectorAlternates();
  }

  // The detector's own points where another proposal (the fit made from them) is offered instead and lies
  // more than ALTERNATE_PX away: drawn as a D ring beside it, so the annotator sees where the two disagree
  // (click it to take the detector's point). view id -> keypoint -> proposal.
  detectorAlternates() {
    const out = new Map(this.annotation.viewIds.map((v) => [v, new Map()]));
    const detector = (this.sources || []).find((s) => s.kind === "detector");
    if (!detector) return out;
    for (const viewId of this.annotation.viewIds) {
      const cam = this.cameras.get(viewId);
      const points = detector.views[String(viewId)] || [];
      for (const [k, chosen] of this.proposals.get(viewId)) {
        const p = points[k];
        const confidence = detector.confidences ? detector.confidences[k] : null;
        if (chosen.source === "detector" || !inside(p, cam) || (confidence !== null && confidence < MIN_CONF)) continue;
        if (Math.hypot(p[0] - chosen.x, p[1] - chosen.y) <= ALTERNATE_PX) continue;
        out.get(viewId).set(k, { x: p[0], y: p[1], source: "detector", confidence });
      }
    }
    return out;
  }

  // Pick the next keypoint to work on: after a placement (afterClick) the next one without a position in
  // this view, not-annotated ones included (a click then sets it: docs/ui.md); after N or an accept, the next
  // one with nothing decided. None left here: the first undecided one of the next view that has one, else
  // (afterClick) the first one without a position of the next view that has one.
  advance({ afterClick = false } = {}) {
    if (!this.autoAdvance) return;
    const next = this.annotation.firstUnset(this.view.id, this.keypoint, { placedToo: afterClick });
    if (next !== null) {
      this.keypoint = next;
    } else {
      const passes = afterClick ? [false, true] : [false];
      search: for (const placedToo of passes) {
        for (let i = 1; i < this.views.length; i++) {
          const idx = (this.viewIndex + i) % this.views.length;
          const k = this.annotation.firstUnset(this.views[idx].id, -1, { placedToo });
          if (k !== null) {
            this.selectView(idx);
            this.keypoint = k;
            break search;
          }
        }
      }
    }
    this.renderSide();
  }

  acceptProposal(keypoint, { advance = true, alternate = false } = {}) {
    const p = (alternate ? this.alternates : this.proposals).get(this.view.id).get(keypoint);
    if (!p) return false;
    // One gesture for occlusion: a keypoint the fit's mesh hides here is accepted as occluded (O flips it).
    this.setClick(this.view.id, keypoint, { x: p.x, y: p.y, visibility: p.hidden ? "occluded" : "visible",
      from: p.source, confidence: p.confidence }, "accept");
    if (advance) this.advance();
    return true;
  }

  acceptAllInView() {
    const all = [...this.proposals.get(this.view.id)];
    const sure = all.filter(([, p]) => confident(p)).map(([k]) => k);
    for (const k of sure) this.acceptProposal(k, { advance: false });
    this.justPlaced = null;
    const left = all.length - sure.length;
    const hidden = all.filter(([k, p]) => sure.includes(k) && p.hidden).length;
    const occluded = hidden ? ` (${hidden} as occluded: the fit's mesh hides them; a digit then O flips one)` : "";
    if (all.length === 0) toast("no proposals left in this view", "info", 1500);
    else if (left) toast(`accepted ${sure.length}${occluded}; ${left} below ${ACCEPT_CONF} ringed orange: have a look ` +
      "(A accepts one)", "info", 3000);
    else if (hidden) toast(`accepted ${sure.length}${occluded}`, "info", 3000);
    if (left) {
      // Stay on the first doubtful one, so the next key is about it.
      this.keypoint = all.find(([, p]) => !confident(p))[0];
      this.renderSide();
      this.requestRender();
    } else {
      this.advance();
    }
  }

  // What O and N apply to: the point just placed (while it is still set), else the picked keypoint here.
  target() {
    const j = this.justPlaced;
    // Only in the view on screen: after the page moved on to the next view, O and N act on what is shown.
    if (j && j.viewId === this.view.id && this.annotation.get(j.viewId, j.keypoint)) return { ...j, justPlaced: true };
    return { viewId: this.view.id, keypoint: this.keypoint, justPlaced: false };
  }

  // An explicit choice of keypoint or view: O and N follow it from now on.
  pick(keypoint) {
    this.justPlaced = null;
    this.keypoint = keypoint;
    this.requestRender();
    this.renderSide();
  }

  toggleOccluded() {
    const { viewId, keypoint } = this.target();
    const click = this.annotation.get(viewId, keypoint);
    if (!click || click.visibility === "not_annotated") {
      const p = this.proposals.get(viewId).get(keypoint);
      if (!p) return toast("place the keypoint first (its best guess), then mark it occluded", "info", 2500);
      return this.setClick(viewId, keypoint, { x: p.x, y: p.y, visibility: "occluded" }, "occlude");
    }
    const visibility = click.visibility === "occluded" ? "visible" : "occluded";
    this.setClick(viewId, keypoint, { ...click, visibility }, "occlude");
  }

  markNotAnnotated() {
    const { viewId, keypoint, justPlaced } = this.target();
    this.setClick(viewId, keypoint, { x: null, y: null, visibility: "not_annotated" }, "not_annotated");
    this.justPlaced = null;
    if (!justPlaced) this.advance(); // after a placement the selection has already moved on
  }

  clearKeypoint() {
    if (this.annotation.get(this.view.id, this.keypoint)) this.setClick(this.view.id, this.keypoint, null, "click");
  }

  // The view's automatic mask as bits and overlay (decoded from its bitmap the first time it is needed).
  decodeMask(view) {
    if (!view.mask && view.maskImage) {
      view.mask = decodeMask(view.maskImage, view.width, view.height);
      view.overlay = new MaskOverlay(view.mask);
    }
    return view.mask;
  }

  // The other views' masks one per idle moment after the page is usable, each thumbnail redrawn after.
  decodeRestLater(sampleId) {
    const pending = this.views.filter((v) => !v.mask && v.maskImage);
    const next = () => {
      const view = pending.shift();
      if (!view || !this.task || this.task.sample_id !== sampleId) return;
      this.decodeMask(view);
      this.renderThumb(this.views.indexOf(view));
      setTimeout(next, 0);
    };
    setTimeout(next, 50);
  }

  ensureMask(view) {
    this.decodeMask(view);
    if (!view.mask) {
      view.mask = new MaskLayer(view.width, view.height);
      view.overlay = new MaskOverlay(view.mask);
    }
    return view.mask;
  }

  // --- drafts and leases --------------------------------------------------------------------------

  // The page's state as a draft (PUT .../draft): the clicks set so far, the corrected masks, where the
  // annotator is, the time spent and the submission id (a submit retried after a reload stays idempotent).
  draftBody() {
    if (!this.task) return null;
    const clicks = [];
    for (const [viewId, byKeypoint] of this.annotation.clicks) {
      for (const [keypoint, c] of byKeypoint) {
        clicks.push(c.visibility === "not_annotated" ? { view_id: viewId, keypoint, visibility: "not_annotated" }
          : { view_id: viewId, keypoint, x: c.x, y: c.y, visibility: c.visibility, from_proposal: Boolean(c.from) });
      }
    }
    const masks = this.views.filter((v) => v.maskEdited && v.mask)
      .map((v) => ({ view_id: v.id, width: v.width, height: v.height, rle: v.mask.toRLE() }));
    return { lease_token: this.task.lease_token, submission_id: this.submissionId,
      time_spent_s: Math.round(this.timer.spentSeconds() * 1000) / 1000, clicks, masks,
      view_index: this.viewIndex, keypoint: this.keypoint, no_hand_views: [...this.noHand] };
  }

  // Restore a saved draft over the freshly shown task (it holds the whole state: it replaces previous clicks).
  applyDraft(draft) {
    const p = draft.payload;
    for (const byKeypoint of this.annotation.clicks.values()) byKeypoint.clear();
    let outside = 0;
    for (const c of p.clicks) {
      if (!this.annotation.clicks.has(c.view_id) || !this.annotation.keypoints.includes(c.keypoint)) continue;
      // A click outside the image (saved by an older page): the server refuses every save holding it: dropped.
      const view = this.views.find((v) => v.id === c.view_id);
      if (c.x !== null && c.x !== undefined && !inside([c.x, c.y], view)) { outside++; continue; }
      const value = { x: c.x ?? null, y: c.y ?? null, visibility: c.visibility };
      if (c.from_proposal) value.from = "proposal"; // accepted, not placed by hand (its source is not kept)
      this.annotation.set(c.view_id, c.keypoint, value);
    }
    for (const m of p.masks) {
      const view = this.views.find((v) => v.id === m.view_id);
      if (!view || view.width !== m.width || view.height !== m.height) continue;
      view.mask = MaskLayer.fromRLE(m.rle, m.width, m.height);
      view.overlay = new MaskOverlay(view.mask);
      view.maskEdited = true;
    }
    this.noHand = new Set((p.no_hand_views || []).filter((id) => this.annotation.clicks.has(id)));
    this.viewIndex = Math.min(p.view_index, this.views.length - 1);
    if (this.annotation.keypoints.includes(p.keypoint)) this.keypoint = p.keypoint;
    const saved = new Date(draft.updated_at).toLocaleTimeString();
    window.__handloop.marks.draftRestored = performance.now();
    if (outside) toast(`${outside} point(s) of your draft lay outside the image: dropped, place them again`, "warn", 8000);
    if (draft.left_by) { // work left on a lapsed lease travels with the sample; this submission and time are ours
      document.body.dataset.draftLeftBy = draft.left_by;
      toast(`sample ${this.task.sample_id}: carrying on from the work ${draft.left_by} left on it (saved ${saved})`,
        "info", 5000);
      return;
    }
    this.submissionId = p.submission_id;
    this.timer.carriedMs = p.time_spent_s * 1000;
    toast(`restored your work on sample ${this.task.sample_id} (saved ${saved})`, "info", 2500);
  }

  draftStatus(state, detail) {
    if (this.lostLease) state = "lost"; // the panel says what the banner says
    document.body.dataset.draftState = state;
    if (state === "saved") document.body.dataset.draftSaved = String(detail.revision);
    if (state === "error" && detail && detail.status && detail.status < 500 && detail.status !== 403 &&
        detail.status !== 409) toast(`work in progress not saved: ${detail.message}`, "warn", 5000);
    const el = this.side.querySelector(".draft-state");
    if (el) el.textContent = draftLabel(state);
  }

  // Another tab or window saved this sample's draft meanwhile (a version per draft: the server refused this
  // page's save, writing nothing): both are shown, the person keeps one; nothing is overwritten unseen.
  draftConflict(theirs) {
    if (!this.task || theirs.sample_id !== this.task.sample_id) return;
    const placed = (clicks) => clicks.filter((c) => c.visibility !== "not_annotated").length;
    const mine = this.draftBody();
    const at = new Date(theirs.updated_at).toLocaleTimeString();
    fill(this.banner, h("strong", {}, `Sample ${theirs.sample_id} was also changed in another tab or window. `),
      h("span", { class: "conflict-both" }, `There (saved ${at}): ${placed(theirs.payload.clicks)} points placed, ` +
        `${theirs.payload.masks.length} masks; here: ${placed(mine.clicks)} points placed, ${mine.masks.length} ` +
        "masks. Keep one: "),
      h("button", { class: "primary keep-mine", onclick: () => {
        this.hideBanner();
        this.drafts.keepMine(theirs);
      } }, "Keep this tab's work"),
      h("button", { class: "take-theirs", onclick: () => {
        this.hideBanner();
        this.applyDraft(theirs);
        this.drafts.takeTheirs(theirs);
        this.history.clear();
        this.updateProposals();
        this.renderNow(true);
        this.renderSide();
      } }, "Take the other"));
    this.banner.hidden = false;
    document.body.dataset.draftConflict = String(theirs.revision);
  }

  leaseRetaken(sampleId, token) {
    if (this.prepared && this.prepared.task.sample_id === sampleId) this.prepared.task.lease_token = token;
    if (!this.task || this.task.sample_id !== sampleId) return;
    this.task.lease_token = token;
    this.hideBanner();
    this.drafts.resume();
    toast(`your lease on sample ${sampleId} had lapsed: taken again, nothing lost`, "info", 3000);
  }

  leaseLost(sampleId, error) {
    if (this.prepared && this.prepared.task.sample_id === sampleId) {
      this.prepared = null; // the prefetched sample went to someone else: fetch another when needed
      return;
    }
    if (!this.task || this.task.sample_id !== sampleId) return;
    this.lostLease = true;
    // What was saved goes with the sample to its new holder (backend/services/drafts.py); later changes could not be.
    const saved = document.body.dataset.draftSaved ? "Your work up to the last save goes with the sample to whoever " +
      "holds it now; changes since then could not be saved." : "None of your work on it was saved.";
    fill(this.banner, h("strong", {}, `Sample ${sampleId} is no longer yours. `),
      h("span", {}, `${error.message}. ${saved}`),
      h("button", { class: "primary next-task", onclick: () => this.giveUp() }, "Take the next task"));
    this.banner.hidden = false;
    document.body.dataset.lease = "lost";
    this.draftStatus("lost");
    this.renderSide();
  }

  hideBanner() {
    this.lostLease = false;
    delete document.body.dataset.draftConflict;
    this.banner.hidden = true;
    fill(this.banner, );
    delete document.body.dataset.lease;
  }

  async giveUp() {
    if (!this.task) return;
    this.drafts.forget();
    this.leases.drop(this.task.sample_id, false);
    this.hideBanner();
    this.task = null;
    // The prefetched sample's lease lapsed with this one's (the laptop slept): it may have gone on to someone
    // else and to review. Taken again (renewed when still live) before it is shown, else dropped (leaseLost).
    if (this.prepared) {
      const token = await this.leases.retake(this.prepared.task.sample_id).catch(() => null);
      if (token && this.prepared) this.prepared.task.lease_token = token;
      else this.prepared = this.preparing = null; // gone on: a fresh task from the queue
    }
    await this.loadNext();
  }

  // --- pointer ------------------------------------------------------------------------------------

  screenPoint(e) {
    const r = this.canvas.getBoundingClientRect();
    return [e.clientX - r.left, e.clientY - r.top];
  }

  hit(sx, sy) {
    let best = null, bestD = HIT_PX;
    const consider = (k, x, y, kind) => {
      if (x === null || y === null) return;
      const [px, py] = this.vp.toScreen(x, y);
      const d = Math.hypot(px - sx, py - sy);
      if (d < bestD) { bestD = d; best = { keypoint: k, kind, x, y }; }
    };
    for (const [k, c] of this.annotation.clicks.get(this.view.id)) consider(k, c.x, c.y, "click");
    for (const [k, p] of this.proposals.get(this.view.id)) consider(k, p.x, p.y, "proposal");
    for (const [k, p] of this.alternates.get(this.view.id)) consider(k, p.x, p.y, "alternate");
    return best;
  }

  pointerdown(e) {
    if (!this.task) return;
    this.timer.input();
    this.canvas.focus();
    try {
      this.canvas.setPointerCapture(e.pointerId);
    } catch {
      // synthetic events (tests, benchmarks) have no active pointer to capture
    }
    const [sx, sy] = this.screenPoint(e);
    const pan = e.button === 1 || e.button === 2 || (e.button === 0 && this.keys.has("Space"));
    if (pan) {
      this.drag = { type: "pan", sx, sy };
      return;
    }
    if (e.button !== 0) return;
    const [u, v] = this.vp.toImage(sx, sy);
    if (this.mode === "mask") {
      const layer = this.ensureMask(this.view);
      const value = this.tool === "brush" ? 1 : 0;
      this.drag = { type: "stroke", recorder: new StrokeRecorder(layer), last: [u, v], value, view: this.view };
      this.strokeTo(u, v);
      return;
    }
    const target = this.hit(sx, sy);
    if (target) {
      // Decided on release: a drag moves this point; a click places the current keypoint if it is unset.
      this.drag = { type: "point", keypoint: target.keypoint, from: target.kind, sx, sy, moved: false, u: target.x,
        v: target.y, pressU: u, pressV: v };
    } else {
      const existing = this.annotation.get(this.view.id, this.keypoint);
      const visibility = existing && existing.visibility === "occluded" ? "occluded" : "visible";
      this.drag = { type: "place", keypoint: this.keypoint, sx, sy, u, v, visibility };
    }
    this.requestRender();
  }

  pointermove(e) {
    if (this.timer) this.timer.input();
    const [sx, sy] = this.screenPoint(e);
    const previous = this.hover;
    // Past the canvas's edge (a drag keeps the pointer captured, so no pointerleave comes): no magnifier there.
    const r = this.canvas.getBoundingClientRect();
    this.hover = sx >= 0 && sy >= 0 && sx <= r.width && sy <= r.height ? [sx, sy] : null;
    const d = this.drag;
    if (!d) {
      if (this.mode === "mask") this.requestRender(this.cursorRect(previous), this.cursorRect(this.hover));
      else if (this.view && this.view.image) {
        const before = this.loupeGeometry(previous), now = this.loupeGeometry(this.hover);
        this.requestRender(before && before.rect, now && now.rect);
      }
      return;
    }
    if (d.type === "pan") {
      this.vp.pan(sx - d.sx, sy - d.sy);
      d.sx = sx;
      d.sy = sy;
    } else if (d.type === "stroke") {
      const [u, v] = this.vp.toImage(sx, sy);
      const rect = this.strokeTo(u, v);
      // A stroke redraws only what it changed and where the cursor was and is (measured by bench ui).
      this.requestRender(rect && this.imageRectOnScreen(rect), this.cursorRect(previous), this.cursorRect(this.hover));
      return;
    } else {
      if (Math.hypot(sx - d.sx, sy - d.sy) > DRAG_PX) d.moved = true;
      [d.u, d.v] = this.vp.toImage(sx, sy);
    }
    this.requestRender();
  }

  strokeTo(u, v) {
    const d = this.drag;
    const layer = d.view.mask;
    const radius = this.radius / 1; // radius is in image pixels
    const rect = layer.stroke(d.last[0], d.last[1], u, v, radius, d.value);
    d.last = [u, v];
    if (rect) {
      d.view.overlay.refresh(rect);
      d.recorder.add(rect);
    }
    return rect;
  }

  imageRectOnScreen(rect) {
    const [x0, y0] = this.vp.toScreen(rect.x - 0.5, rect.y - 0.5);
    const [x1, y1] = this.vp.toScreen(rect.x + rect.w - 0.5, rect.y + rect.h - 0.5);
    return { x: x0 - 2, y: y0 - 2, w: x1 - x0 + 4, h: y1 - y0 + 4 };
  }

  cursorRect(point) {
    if (!point) return null;
    const r = this.radius * this.vp.scale + 3;
    return { x: point[0] - r, y: point[1] - r, w: 2 * r, h: 2 * r };
  }

  pointerup(e) {
    const d = this.drag;
    this.drag = null;
    if (!d) return;
    if (this.canvas.hasPointerCapture(e.pointerId)) this.canvas.releasePointerCapture(e.pointerId);
    if (d.type === "stroke") {
      const view = d.view;
      const command = d.recorder.finish((rect) => { view.overlay.refresh(rect); this.changed(view.id); });
      if (command) {
        view.maskEdited = true;
        this.history.record({ kind: "mask", ...command, undo: command.undo, redo: command.redo });
        this.timer.mark(d.value ? "brush" : "erase", { view_id: view.id });
        this.changed(view.id);
      }
    } else if (d.type === "place") {
      if (this.placeable(d.u, d.v)) {
        this.setClick(this.view.id, d.keypoint, { x: d.u, y: d.v, visibility: d.visibility }, "click");
        this.advance({ afterClick: true });
      }
    } else if (d.type === "point") {
      // A not-annotated keypoint is unset: a click on another point places it there (docs/ui.md).
      const currentUnset = !this.annotation.placed(this.view.id, this.keypoint);
      if (d.moved && !this.placeable(d.u, d.v)) {
        // dropped outside the image: the point stays where it was
      } else if (d.moved) {
        this.keypoint = d.keypoint;
        const existing = this.annotation.get(this.view.id, d.keypoint);
        const offered = d.from === "proposal" ? this.proposals.get(this.view.id).get(d.keypoint) : null;
        const occluded = existing ? existing.visibility === "occluded" : Boolean(offered && offered.hidden);
        this.setClick(this.view.id, d.keypoint, { x: d.u, y: d.v, visibility: occluded ? "occluded" : "visible" }, "drag");
        if (d.from !== "click") this.advance();
      } else if (d.keypoint !== this.keypoint && currentUnset) {
        if (this.placeable(d.pressU, d.pressV)) {
          this.setClick(this.view.id, this.keypoint, { x: d.pressU, y: d.pressV, visibility: "visible" }, "click");
          this.advance({ afterClick: true });
        }
      } else if (d.from === "proposal" || d.from === "alternate") {
        this.keypoint = d.keypoint;
        this.acceptProposal(d.keypoint, { alternate: d.from === "alternate" });
      } else {
        this.keypoint = d.keypoint;
        this.renderSide();
      }
    }
    this.requestRender();
  }

  // Whether image point (u, v) lies in the view's image; if not, says so (nothing is placed outside it).
  placeable(u, v) {
    if (inside([u, v], this.view)) return true;
    toast(`outside ${this.view.camera}'s image: nothing placed (click on the image)`, "warn", 2500);
    document.body.dataset.refused = "outside";
    return false;
  }

  wheel(e) {
    e.preventDefault();
    if (!this.task) return;
    this.timer.input();
    if (this.mode === "mask" && !e.ctrlKey) {
      this.setRadius(this.radius * (e.deltaY < 0 ? 1.15 : 1 / 1.15));
      return;
    }
    const [sx, sy] = this.screenPoint(e);
    this.vp.zoomAt(Math.exp(-e.deltaY * 0.0015), sx, sy);
    this.requestRender();
  }

  setRadius(r) {
    this.radius = Math.max(1, Math.min(200, r));
    this.requestRender();
    this.renderSide();
  }

  // --- keys ---------------------------------------------------------------------------------------

  keydown(e) {
    if (!this.task || isTyping(e)) return;
    this.timer.input();
    this.keys.add(e.code);
    const ctrl = e.ctrlKey || e.metaKey;
    const key = e.key;
    let handled = true;
    if (ctrl && (key === "z" || key === "Z")) {
      if (e.shiftKey) this.redo(); else this.undo();
    } else if (ctrl && (key === "y" || key === "Y")) {
      this.redo();
    } else if (ctrl && key === "Enter") {
      this.submit({ confirmed: this.asking === "submit" });
    } else if (ctrl) {
      handled = false;
    } else if (key >= "1" && key <= "6") {
      this.pick(SPARSE[Number(key) - 1]);
    } else if (key === "Escape" && this.asking) {
      this.closeAsk();
    } else if (key === "x" || key === "X") {
      this.toggleNoHand();
    } else if (key === "Escape") {
      // Keys back to the view from whatever has the focus (a button, the list); a drag in progress ends.
      this.drag = null;
      if (document.activeElement && document.activeElement !== this.canvas) document.activeElement.blur();
      this.canvas.focus();
      this.side.querySelector(".help").removeAttribute("open");
      this.requestRender();
    } else if (key === "Tab") {
      this.justPlaced = null;
      this.selectView((this.viewIndex + (e.shiftKey ? this.views.length - 1 : 1)) % this.views.length);
    } else if (key === "a" || key === "A") {
      if (!this.acceptProposal(this.keypoint)) toast("no proposal for this keypoint here", "info", 1500);
    } else if (key === "Enter") {
      this.acceptAllInView();
    } else if (key === "o" || key === "O") {
      this.toggleOccluded();
    } else if (key === "n" || key === "N") {
      this.markNotAnnotated();
    } else if (key === "Delete" || key === "Backspace") {
      this.clearKeypoint();
    } else if (key === "m" || key === "M") {
      this.setMode(this.mode === "mask" ? "points" : "mask");
    } else if (key === "b" || key === "B") {
      this.tool = "brush";
      this.setMode("mask");
    } else if (key === "e" || key === "E") {
      this.tool = "eraser";
      this.setMode("mask");
    } else if (key === "p" || key === "P") {
      this.setMode("points");
    } else if (key === "[") {
      this.setRadius(this.radius / 1.25);
    } else if (key === "]") {
      this.setRadius(this.radius * 1.25);
    } else if (key === "h" || key === "H") {
      this.showMask = !this.showMask;
      this.timer.mark("toggle");
      this.requestRender();
      this.buildThumbs();
    } else if (key === "0") {
      // The hand; pressed again (already there), the whole image.
      const before = [this.vp.scale, this.vp.ox, this.vp.oy];
      this.fitView();
      if (Math.abs(before[0] - this.vp.scale) < 1e-9 && Math.abs(before[1] - this.vp.ox) < 1e-6) this.fitView({ whole: true });
      this.requestRender();
    } else if (key === "+" || key === "=") {
      this.zoomCentre(1.25);
    } else if (key === "-") {
      this.zoomCentre(0.8);
    } else if (key === "?") {
      this.side.querySelector(".help").toggleAttribute("open");
    } else if (key === " ") {
      // Space + drag pans; keep the page from scrolling.
    } else {
      handled = false;
    }
    if (handled) e.preventDefault();
  }

  zoomCentre(factor) {
    const r = this.canvas.getBoundingClientRect();
    this.vp.zoomAt(factor, r.width / 2, r.height / 2);
    this.requestRender();
  }

  setMode(mode) {
    this.mode = mode;
    this.canvas.classList.toggle("mask-mode", mode === "mask");
    this.requestRender();
    this.renderSide();
  }

  undo() {
    this.justPlaced = null;
    const c = this.history.undo();
    if (c) this.timer.mark("undo");
  }

  redo() {
    this.justPlaced = null;
    const c = this.history.redo();
    if (c) this.timer.mark("redo");
  }

  selectView(index) {
    if (index === this.viewIndex) return;
    this.keepZoom();
    this.viewIndex = index;
    this.decodeMask(this.view);
    this.timer.mark("view", { view_id: this.view.id });
    this.keypoint = this.annotation.firstUnset(this.view.id) ??
      this.annotation.firstUnset(this.view.id, -1, { placedToo: true }) ?? this.keypoint;
    this.restoreZoom();
    this.requestRender();
    for (const [i, el] of [...this.thumbs.children].entries()) el.classList.toggle("active", i === index);
    this.renderSide();
  }

  // Fit the view to the hand (its clicks and proposals, else its automatic mask), or with whole=true (or no
  // hand found) to the whole image.
  fitView({ whole = false } = {}) {
    if (!this.task) return;
    const { width, height } = fitCanvas(this.canvas);
    const view = this.view;
    const box = whole ? null : this.handBox(view);
    const wholeScale = Math.min((width - 16) / view.width, (height - 16) / view.height);
    if (box) {
      this.vp.fitRect(...box, width, height, 8);
      // No closer than OPEN_MAX_PX screen px per working-copy pixel (unless the whole image shows larger):
      // zoomed further, a 640 px copy opened at 483 % looked blocky. The hand stays centred.
      const copyWidth = view.image ? view.image.width : view.width;
      const most = Math.max(OPEN_MAX_PX * copyWidth / view.width, 1.25 * wholeScale);
      if (this.vp.scale > most) {
        const cx = (box[0] + box[2]) / 2, cy = (box[1] + box[3]) / 2;
        this.vp.scale = most;
        this.vp.ox = width / 2 - (cx + 0.5) * most;
        this.vp.oy = height / 2 - (cy + 0.5) * most;
        this.vp.minScale = most / 8;
      }
      // No blank beyond the image's edge: a hand at the edge once opened as a strip of arm beside empty canvas.
      this.vp.keepInside(view.width, view.height, width, height);
    } else {
      this.vp.fit(view.width, view.height, width, height);
    }
    this.vp.minScale = Math.min(this.vp.minScale, Math.min(width / view.width, height / view.height) / 2);
  }

  // The image rectangle [x0, y0, x1, y1] around the hand in a view, with a margin; null if nothing shows it.
  handBox(view, margin = 0.35, minFraction = 0.2) {
    const xs = [], ys = [];
    // Only points inside the image: a source's projection off the image once opened a view on a strip of arm
    // at its edge.
    const add = (x, y) => {
      if (Number.isFinite(x) && Number.isFinite(y) && x >= 0 && y >= 0 && x <= view.width && y <= view.height) {
        xs.push(x);
        ys.push(y);
      }
    };
    for (const c of this.annotation.clicks.get(view.id).values()) add(c.x, c.y);
    for (const p of (this.proposals ? this.proposals.get(view.id) : new Map()).values()) add(p.x, p.y);
    for (const source of this.sources || []) for (const p of source.views[String(view.id)] || []) if (p) add(p[0], p[1]);
    let box = null;
    if (xs.length >= 2) {
      box = [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
    } else if (view.overlay) {
      box = view.overlay.bounds();
      margin = 0.15;
    }
    if (!box) return null;
    const [x0, y0, x1, y1] = box;
    const w = Math.max((x1 - x0) * (1 + 2 * margin), view.width * minFraction);
    const hh = Math.max((y1 - y0) * (1 + 2 * margin), view.height * minFraction);
    const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
    return [cx - w / 2, cy - hh / 2, cx + w / 2, cy + hh / 2];
  }

  zoomKey(view = this.view) {
    return `${this.task.sample_id}/${view.id}`;
  }

  keepZoom() {
    if (!this.task || !this.view) return;
    const { scale, ox, oy, minScale } = this.vp;
    this.zooms.set(this.zoomKey(), { scale, ox, oy, minScale });
  }

  restoreZoom() {
    const kept = this.zooms.get(this.zoomKey());
    if (kept) Object.assign(this.vp, kept);
    else this.fitView();
  }

  // --- submit -------------------------------------------------------------------------------------

  showAsk(kind, ...children) {
    this.asking = kind;
    fill(this.ask, ...children);
    this.ask.hidden = false;
    document.body.dataset.ask = kind;
  }

  closeAsk() {
    this.asking = null;
    this.ask.hidden = true;
    fill(this.ask, );
    delete document.body.dataset.ask;
  }

  // "No hand here" in the view on screen: every point of it not annotated (one undo step), the view sent as
  // no_hand_views with the submission (kept out of the fit, counted). Again: the mark goes, the points unset.
  toggleNoHand() {
    const viewId = this.view.id;
    const on = !this.noHand.has(viewId);
    const changes = this.annotation.keypoints.map((keypoint) => ({ keypoint,
      previous: this.annotation.get(viewId, keypoint),
      value: on ? { x: null, y: null, visibility: "not_annotated" } : null }));
    const apply = (which, mark) => {
      for (const c of changes) this.annotation.set(viewId, c.keypoint, c[which]);
      if (mark) this.noHand.add(viewId); else this.noHand.delete(viewId);
      this.justPlaced = null;
      this.changed(viewId);
    };
    this.history.record({ kind: "no_hand", undo: () => apply("previous", !on), redo: () => apply("value", on) });
    this.timer.mark("not_annotated", { view_id: viewId });
    apply("value", on);
  }

  // Skip the sample or mark it "no hand" (every view), with a reason, after asking.
  askPass(kind) {
    const input = h("input", { class: "pass-reason", type: "text", maxlength: "500", "aria-label": "reason",
      value: kind === "no_hand" ? "no hand in any view" : "", placeholder: "why (required)" });
    const send = () => this.passOn(kind, input.value);
    input.addEventListener("keydown", (e) => { if (e.key === "Enter") { e.preventDefault(); send(); } });
    this.showAsk(kind, h("strong", {}, kind === "no_hand" ? "No hand in this sample: " : "Skip this sample: "),
      h("span", {}, kind === "no_hand" ? "it leaves the queue (nothing to label or fit). "
        : "it goes to another annotator, not back to you. "),
      input,
      h("button", { class: "primary confirm-pass", onclick: send }, kind === "no_hand" ? "Mark no hand" : "Skip"),
      h("button", { class: "keep", onclick: () => this.closeAsk() }, "Keep annotating (Esc)"));
    input.focus();
  }

  async passOn(kind, reason) {
    if (!this.task) return;
    if (!reason.trim()) return toast("give a reason", "warn", 2500);
    const task = this.task;
    try {
      let result;
      const url = paths.skip(task.sample_id);
      const body = { kind, reason: reason.trim(), lease_token: task.lease_token };
      try {
        result = await this.api.post(url, body);
      } catch (error) {
        if (error.status !== 403 && error.status !== 409) throw error;
        body.lease_token = await this.leases.retake(task.sample_id);
        result = await this.api.post(url, body);
      }
      this.closeAsk();
      this.drafts.forget();
      this.leases.drop(task.sample_id, false);
      toast(kind === "no_hand" ? `sample ${task.sample_id}: no hand (${result.state})`
        : `skipped sample ${task.sample_id}: it goes to someone else`, "ok", 2500);
      this.task = null;
      await this.loadNext();
    } catch (error) {
      toast(`${kind === "no_hand" ? "no hand" : "skip"} failed: ${error.message}`, "error", 8000);
    }
  }

  // After a submission, look for its fit failing (every 5 s, for 2 minutes): shown on the page, with why.
  watchFit(submissionId, tries = 24) {
    clearTimeout(this.fitWatch);
    const look = async () => {
      const failures = await this.api.get(paths.fitFailures()).catch(() => null);
      if (failures) {
        const fresh = failures.filter((f) => !this.failedFits.some((g) => g.submission_id === f.submission_id));
        const mine = failures.find((f) => f.submission_id === submissionId);
        if (fresh.length) {
          this.failedFits = failures.slice(0, 3);
          for (const f of fresh) toast(`the fit of your work on sample ${f.sample_id} failed: ${f.reason}`, "warn", 10000);
          if (this.lastSubmission && mine && this.lastSubmission.submission === submissionId) {
            this.lastSubmission.failed = mine.reason;
          }
          document.body.dataset.fitFailed = String(failures[0].sample_id);
          this.renderSide();
        }
        if (mine) return;
      }
      if (--tries > 0) this.fitWatch = setTimeout(look, 5000);
    };
    this.fitWatch = setTimeout(look, 1000);
  }

  // What a submit would leave out: points not set (they go as not annotated) outside the views marked "no hand",
  // and whether anything at all is placed.
  submitGaps() {
    let unset = 0, placed = 0, views = 0;
    for (const viewId of this.annotation.viewIds) {
      if (this.noHand.has(viewId)) continue;
      let here = 0;
      for (const k of this.annotation.keypoints) {
        const c = this.annotation.get(viewId, k);
        if (c === null) here++;
        else if (c.x !== null) placed++;
      }
      unset += here;
      if (here) views++;
    }
    return { unset, placed, views, masks: this.views.some((v) => v.maskEdited) };
  }

  // Submit; an empty submission is not sent (nothing to fit) and an incomplete one asks first.
  async submit({ confirmed = false } = {}) {
    if (!this.task || this.submitting) return;
    if (this.lostLease) return toast("this sample is no longer yours: take the next task", "warn", 3000);
    const gaps = this.submitGaps();
    if (gaps.placed === 0 && !gaps.masks) {
      return this.showAsk("empty", h("strong", {}, "Nothing is placed: there is nothing to fit. "),
        h("span", {}, "If no view shows the hand, mark the sample 'no hand'; if you cannot annotate it, skip it."),
        h("button", { class: "no-hand-sample", onclick: () => this.askPass("no_hand") }, "No hand in this sample…"),
        h("button", { class: "skip-sample", onclick: () => this.askPass("skip") }, "Skip…"),
        h("button", { class: "keep", onclick: () => this.closeAsk() }, "Keep annotating (Esc)"));
    }
    if (gaps.unset > 0 && !confirmed) {
      return this.showAsk("submit", h("strong", {}, `${gaps.unset} point(s) not set in ${gaps.views} view(s). `),
        h("span", {}, "They are submitted as not annotated. Submit anyway?"),
        h("button", { class: "primary confirm-submit", onclick: () => this.submit({ confirmed: true }) },
          "Submit anyway (Ctrl+Enter)"),
        h("button", { class: "keep", onclick: () => this.closeAsk() }, "Keep annotating (Esc)"));
    }
    this.closeAsk();
    const task = this.task;
    const masks = this.views.filter((v) => v.maskEdited && v.mask)
      .map((v) => ({ view_id: v.id, width: v.width, height: v.height, rle: v.mask.toRLE() }));
    const body = {
      submission_id: this.submissionId,
      lease_token: task.lease_token,
      time_spent_s: Math.round(this.timer.spentSeconds() * 1000) / 1000,
      clicks: this.annotation.toClicks(),
      masks,
    };
    if (this.noHand.size) body.no_hand_views = [...this.noHand];
    this.submitting = true;
    this.renderSide();
    try {
      const url = paths.submissions(task.sample_id);
      let result;
      try {
        result = await this.api.post(url, body);
      } catch (error) {
        if (error.status !== 403 && error.status !== 409) throw error;
        // The lease lapsed (or the token is stale): take it again while the sample is free, then submit.
        body.lease_token = await this.leases.retake(task.sample_id);
        result = await this.api.post(url, body);
      }
      this.drafts.forget(); // the server deleted the draft with the submission
      this.leases.drop(task.sample_id, false);
      const log = {
        context: "annotate", sample_id: task.sample_id, submission_id: result.submission_id,
        time_spent_s: body.time_spent_s, actions: this.timer.actions.slice(0, 20000),
      };
      this.api.post(paths.activity(), log).catch((error) => toast(`time log not saved: ${error.message}`, "warn"));
      this.lastSubmission = { sample_id: task.sample_id, fit_job_id: result.fit_job_id, clicks: body.clicks.length,
        masks: masks.length, submission: result.id };
      this.watchFit(result.id);
      toast(`submitted sample ${task.sample_id}: ${masks.length} mask(s), fit job ${result.fit_job_id ?? "–"} queued`,
        "ok", 2500);
      this.submitting = false;
      await this.loadNext();
    } catch (error) {
      this.submitting = false;
      toast(`submit failed: ${error.message}`, "error", 8000);
      this.renderSide();
    }
  }

  // --- rendering ----------------------------------------------------------------------------------

  // Schedule a redraw for the next frame: of the whole view (no rectangles given), or only of the given
  // screen rectangles (null entries are skipped); a full request wins over partial ones.
  requestRender(...rects) {
    if (rects.length === 0) this.dirty = "all";
    else if (this.dirty !== "all") for (const r of rects) if (r) this.dirty = unionRect(this.dirty, r);
    if (this.frame) return;
    this.frame = requestAnimationFrame(() => { this.frame = null; this.renderNow(); });
  }

  // Draw what is pending now (the whole view with force); a scheduled frame is then not needed.
  renderNow(force = false) {
    if (this.frame) { cancelAnimationFrame(this.frame); this.frame = null; }
    const pending = force ? "all" : this.dirty;
    this.dirty = null;
    if (!this.task || !pending) return;
    const dirty = pending === "all" ? null : pending;
    const view = this.view;
    const { width, height, dpr } = fitCanvas(this.canvas);
    const ctx = this.canvas.getContext("2d");
    ctx.save();
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    if (dirty) {
      ctx.beginPath();
      ctx.rect(Math.floor(dirty.x), Math.floor(dirty.y), Math.ceil(dirty.w) + 1, Math.ceil(dirty.h) + 1);
      ctx.clip();
    }
    ctx.fillStyle = "#1b1e24";
    ctx.fillRect(0, 0, width, height);
    this.vp.apply(ctx, dpr);
    ctx.imageSmoothingEnabled = this.vp.scale < 3;
    const image = this.pixelsOf(view, dpr);
    if (image) ctx.drawImage(image, 0, 0, view.width, view.height);  // a working-width copy: full-resolution units
    // Points mode shows the mask's outline only, so the skin under it stays visible.
    if (this.showMask && view.overlay) ctx.drawImage(this.mode === "points" ? view.overlay.outline() : view.overlay.canvas, 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    if (!view.image) {
      ctx.fillStyle = "#9aa0ab";
      ctx.font = "14px system-ui, sans-serif";
      ctx.fillText(`loading ${view.camera}…`, 16, 24);
    }
    if (this.mode === "points" && !this.annotation.get(view.id, this.keypoint)) this.drawEpipolar(ctx, view);
    this.drawPoints(ctx, view, this.vp, { labels: true, selected: this.keypoint });
    const target = this.target();
    const tc = target.viewId === view.id ? this.annotation.get(view.id, target.keypoint) : null;
    if (tc && tc.x !== null && target.justPlaced) {
      // The point O and N will change, when it is not the picked one: a white ring around it.
      const [tx, ty] = this.vp.toScreen(tc.x, tc.y);
      ctx.save();
      ctx.strokeStyle = "#fff";
      ctx.lineWidth = 1.5;
      ctx.setLineDash([2, 2]);
      ctx.beginPath();
      ctx.arc(tx, ty, 14, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.restore();
    }
    if (this.mode === "points" && this.hover && view.image && !this.drag) this.drawLoupe(ctx, view, dpr);
    if (this.mode === "mask" && this.hover) {
      ctx.save();
      ctx.strokeStyle = this.tool === "brush" ? "#4cc9f0" : "#ff6b6b";
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.arc(this.hover[0], this.hover[1], this.radius * this.vp.scale, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.restore();
    }
    ctx.restore();
    if (dirty) return;
    this.hud.textContent = `${view.camera} · ${view.width}×${view.height} · ${Math.round(this.vp.scale * 100)}% · ` +
      (this.mode === "mask" ? `mask: ${this.tool} r=${Math.round(this.radius)} px` : `points: ${labelFor(this.keypoint)}` +
        ` · O/N: ${labelFor(target.keypoint)}${target.justPlaced ? " (just placed)" : ""}`);
  }

  // The pixels to draw a view with: its working-width copy, or once zoomed past that copy's own pixels, the
  // full-resolution original (loaded the first time it is needed, then kept for the view).
  pixelsOf(view, dpr) {
    if (!view.fullImage && !view.fullLoading && needsFullImage(view, this.vp.scale, dpr)) {
      const task = this.task;
      view.fullLoading = loadFullImage(this.api, view).then((bitmap) => {
        view.fullImage = bitmap;
        if (this.task === task && this.view === view) this.requestRender();
      }).catch((error) => {
        toast(`full-resolution ${view.camera} did not load: ${error.message}`, "warn", 4000);
      });
    }
    return view.fullImage || view.image;
  }

  // The magnifier: up to LOUPE_ZOOM times the view's zoom around the cursor, in a circle beside it (clear of
  // the finger that points), with a crosshair on the pixel a click would place.
  loupeGeometry(point = this.hover) {
    if (!point) return null;
    const r = this.canvas.getBoundingClientRect();
    const [x, y] = point;
    const cx = x + (x + LOUPE_OFFSET + LOUPE_R > r.width ? -LOUPE_OFFSET : LOUPE_OFFSET);
    const cy = y + (y - LOUPE_OFFSET - LOUPE_R < 0 ? LOUPE_OFFSET : -LOUPE_OFFSET);
    return { x, y, cx, cy, rect: { x: cx - LOUPE_R - 3, y: cy - LOUPE_R - 3, w: 2 * LOUPE_R + 6, h: 2 * LOUPE_R + 6 } };
  }

  drawLoupe(ctx, view, dpr) {
    const g = this.loupeGeometry();
    const [u, v] = this.vp.toImage(g.x, g.y);
    // LOUPE_ZOOM times the view's zoom, but no more than LOUPE_MAX_PX screen px per image pixel (at least 1.5x).
    const scale = Math.min(this.vp.scale * LOUPE_ZOOM, Math.max(this.vp.scale * 1.5, LOUPE_MAX_PX));
    ctx.save();
    ctx.beginPath();
    ctx.arc(g.cx, g.cy, LOUPE_R, 0, 2 * Math.PI);
    ctx.fillStyle = "#000";
    ctx.fill();
    ctx.clip();
    // Image point (u, v) at the loupe's centre: screen = (px + 0.5) * scale + o.
    ctx.setTransform(scale * dpr, 0, 0, scale * dpr, (g.cx - (u + 0.5) * scale) * dpr, (g.cy - (v + 0.5) * scale) * dpr);
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(view.fullImage || view.image, 0, 0, view.width, view.height);
    if (this.showMask && view.overlay) ctx.drawImage(view.overlay.outline(), 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.strokeStyle = "rgba(255, 255, 255, 0.9)";
    ctx.lineWidth = 1;
    ctx.beginPath();
    ctx.moveTo(g.cx - 8, g.cy);
    ctx.lineTo(g.cx + 8, g.cy);
    ctx.moveTo(g.cx, g.cy - 8);
    ctx.lineTo(g.cx, g.cy + 8);
    ctx.stroke();
    ctx.restore();
    ctx.save();
    ctx.strokeStyle = "#000";
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.arc(g.cx, g.cy, LOUPE_R, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.strokeStyle = "#fff";
    ctx.lineWidth = 1.5;
    ctx.stroke();
    ctx.restore();
    this.loupe = { cx: g.cx, cy: g.cy, u, v, zoom: scale / this.vp.scale };
  }

  // While the picked keypoint is being placed here: the epipolar curve of each view where it was placed by
  // hand (the point lies on all of them; lens distortion bends them slightly).
  drawEpipolar(ctx, view) {
    const camTo = this.cameras.get(view.id);
    if (!camTo) return;
    ctx.save();
    ctx.strokeStyle = colorOf(this.keypoint);
    ctx.globalAlpha = 0.7;
    ctx.lineWidth = 1;
    ctx.setLineDash([6, 4]);
    for (const other of this.views) {
      const c = other.id === view.id ? null : this.annotation.get(other.id, this.keypoint);
      if (!c || c.from || c.x === null) continue;
      const curve = epipolarCurve([c.x, c.y], this.cameras.get(other.id), camTo);
      ctx.beginPath();
      curve.forEach(([u, v], i) => {
        const [sx, sy] = this.vp.toScreen(u, v);
        if (i === 0) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy);
      });
      ctx.stroke();
    }
    ctx.restore();
  }

  // Clicks, proposals and the dragged point of one view, on a 2D context in screen units.
  drawPoints(ctx, view, vp, { labels = false, selected = null, r = 6 } = {}) {
    const clicks = this.annotation.clicks.get(view.id);
    const drag = this.drag && view === this.view && (this.drag.type === "place" || this.drag.type === "point")
      ? this.drag : null;
    const pos = (k, c) => (drag && drag.keypoint === k && (drag.type === "place" || drag.moved) ? [drag.u, drag.v] : [c.x, c.y]);
    const wrist = clicks.get(0);
    if (wrist && wrist.x !== null) {
      for (const k of SPARSE.slice(1)) {
        const c = clicks.get(k);
        if (c && c.x !== null) segment(ctx, vp.toScreen(...pos(0, wrist)), vp.toScreen(...pos(k, c)), colorOf(k), 1, [4, 4]);
      }
    }
    for (const [k, p] of this.alternates.get(view.id)) {
      if (drag && drag.keypoint === k) continue;
      const [x, y] = vp.toScreen(p.x, p.y);
      marker(ctx, x, y, k, { style: "alternate", r, label: labels ? proposalLabel(p) : null });
    }
    for (const [k, p] of this.proposals.get(view.id)) {
      if (drag && drag.keypoint === k) continue;
      const [x, y] = vp.toScreen(p.x, p.y);
      marker(ctx, x, y, k, { style: "proposal", r, label: labels ? proposalLabel(p) : null,
        selected: labels && selected === k, look: !confident(p) });
    }
    for (const [k, c] of clicks) {
      if (c.x === null) continue;
      const [x, y] = vp.toScreen(...pos(k, c));
      marker(ctx, x, y, k, { style: c.visibility === "occluded" ? "occluded" : "solid", r,
        selected: labels && selected === k });
    }
    if (drag && drag.type === "place" && !clicks.has(drag.keypoint)) {
      const [x, y] = vp.toScreen(drag.u, drag.v);
      marker(ctx, x, y, drag.keypoint, { r, selected: true });
    }
  }

  buildThumbs() {
    fill(this.thumbs, ...this.views.map((view, i) => {
      const canvas = h("canvas", { class: "thumb-canvas" });
      const el = h("button", { class: `thumb${i === this.viewIndex ? " active" : ""}`, title: `${view.camera} (Tab)`,
        onclick: () => { this.justPlaced = null; this.selectView(i); } }, canvas, h("span", { class: "thumb-label" }, ""));
      view.thumb = { el, canvas };
      return el;
    }));
    requestAnimationFrame(() => this.views.forEach((_, i) => this.renderThumb(i)));
  }

  renderThumb(index) {
    const view = this.views[index];
    if (!view || !view.thumb) return;
    const { canvas, el } = view.thumb;
    const { width, height, dpr } = fitCanvas(canvas);
    const ctx = canvas.getContext("2d");
    const vp = new Viewport().fit(view.width, view.height, width, height, 2);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.fillStyle = "#111";
    ctx.fillRect(0, 0, width, height);
    vp.apply(ctx, dpr);
    if (view.image) ctx.drawImage(view.image, 0, 0, view.width, view.height);  // a working-width copy: full-resolution units
    if (this.showMask && view.overlay) ctx.drawImage(view.overlay.canvas, 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    this.drawPoints(ctx, view, vp, { r: 3 });
    // Placed points out of the keypoints; those marked not annotated apart ("· 2 N"): they are decided, not done.
    const done = this.annotation.doneIn(view.id);
    const skipped = this.annotation.notAnnotatedIn(view.id);
    el.querySelector(".thumb-label").textContent =
      `${index + 1} ${view.camera} ${this.noHand.has(view.id) ? "no hand"
        : `${done}/${this.annotation.keypoints.length}${skipped ? ` · ${skipped} N` : ""}`}` +
      `${view.maskEdited ? " ✎" : ""}`;
    el.classList.toggle("complete", done === this.annotation.keypoints.length);
  }

  renderClock() {
    const el = this.side.querySelector(".clock");
    if (!el || !this.task) return;
    const expires = this.leases.expiresAt(this.task.sample_id);
    const left = expires ? Math.max(0, Math.round((expires - Date.now()) / 1000)) : null;
    if (expires && expires <= Date.now() && !this.lostLease) this.leases.retake(this.task.sample_id).catch(() => null);
    const idle = this.timer.idle() ? ` (paused: no input for ${this.timer.idleCapMs / 1000} s)` : "";
    el.textContent = `time ${fmt(this.timer.spentSeconds(), 0, " s")}${idle} · lease ${left === null ? "–" : `${left} s`}`;
  }

  renderSide() {
    if (!this.task || !this.proposals) return;
    const view = this.view;
    const props = this.proposals.get(view.id);
    const rows = SPARSE.map((k, i) => {
      const status = this.annotation.status(view.id, k);
      const p = props.get(k);
      const alt = this.alternates.get(view.id).get(k);
      const text = status === "unset" ? (p ? `proposal ${proposalLabel(p)}${p.hidden ? " · hidden" : ""}` +
        `${confident(p) ? "" : " · look"}` +
        (alt ? ` · ${proposalLabel(alt)} ${fmt(Math.hypot(alt.x - p.x, alt.y - p.y), 0, " px")} away` : "") : "–")
        : status.replace("_", " ") + (this.annotation.get(view.id, k).from ? " (accepted)" : "");
      return h("li", { class: `kp-row${k === this.keypoint ? " current" : ""} status-${status}`,
        onclick: () => this.pick(k) },
      h("kbd", {}, String(i + 1)), h("span", { class: "swatch", style: { background: colorOf(k) } }),
      h("span", { class: "kp-name" }, SPARSE_LABELS[i]), h("span", { class: "kp-status" }, text));
    });
    const hiddenCount = [...props.values()].filter((p) => confident(p) && p.hidden).length;
    const total = this.views.reduce((n, v) => n + this.annotation.doneIn(v.id), 0);
    const skipped = this.views.reduce((n, v) => n + this.annotation.notAnnotatedIn(v.id), 0);
    const masks = this.views.filter((v) => v.maskEdited).length;
    const t = this.task;
    fill(this.side, 
      h("div", { class: "sample-head" },
        h("h2", {}, `Sample ${t.sample_id}`),
        h("div", { class: "muted" }, `${t.sequence ?? `sequence ${t.sequence_id}`} · frame ${t.frame_index}`),
        handSide(t.side),
        h("div", { class: "clock muted" }, ""),
        h("div", { class: "draft-state muted" }, draftLabel(document.body.dataset.draftState))),
      this.reviewNote ? h("div", { class: "callout" }, h("strong", {}, "Reviewer: "), this.reviewNote) : null,
      this.fitFailure ? h("div", { class: "callout warn fit-failure-here" }, h("strong", {}, "The last fit failed: "),
        this.fitFailure.reason, ". Its points are kept below; place what is missing, or skip the sample.") : null,
      this.failedFits.length ? h("div", { class: "callout warn fit-failures" },
        h("strong", {}, "Fits that failed on your work: "), this.failedFits.map((f) =>
          h("div", {}, `sample ${f.sample_id}: ${f.reason} (it goes to another annotator)`))) : null,
      h("div", { class: "mode-switch", role: "group" },
        h("button", { class: this.mode === "points" ? "on" : "", onclick: () => this.setMode("points") }, "Points (P)"),
        h("button", { class: this.mode === "mask" && this.tool === "brush" ? "on" : "",
          onclick: () => { this.tool = "brush"; this.setMode("mask"); } }, "Brush (B)"),
        h("button", { class: this.mode === "mask" && this.tool === "eraser" ? "on" : "",
          onclick: () => { this.tool = "eraser"; this.setMode("mask"); } }, "Eraser (E)")),
      h("div", { class: "muted" }, `brush radius ${Math.round(this.radius)} px ([ ] or wheel)`),
      h("h3", {}, `View ${this.viewIndex + 1}/${this.views.length} · ${view.camera}`),
      h("ul", { class: "kp-list" }, rows),
      h("div", { class: "button-row" },
        h("button", { class: "accept-all", onclick: () => this.acceptAllInView(), disabled: props.size === 0 },
          `Accept ${[...props.values()].filter(confident).length} of ${props.size} proposals (Enter)` +
          `${hiddenCount ? ` · ${hiddenCount} as occluded` : ""}`),
        h("button", { onclick: () => this.toggleOccluded() }, "Occluded (O)"),
        h("button", { onclick: () => this.markNotAnnotated() }, "Not annotated (N)"),
        h("button", { class: `no-hand-view${this.noHand.has(view.id) ? " on" : ""}`, onclick: () => this.toggleNoHand() },
          this.noHand.has(view.id) ? "No hand here ✓ (X)" : "No hand here (X)")),
      h("div", { class: "button-row" },
        h("button", { onclick: () => this.undo(), disabled: !this.history.canUndo }, "Undo"),
        h("button", { onclick: () => this.redo(), disabled: !this.history.canRedo }, "Redo")),
      h("div", { class: "totals" }, `${total}/${this.views.length * this.annotation.keypoints.length} keypoints placed · ` +
        `${skipped} not annotated · ${masks} mask(s) corrected`),
      h("button", { class: "primary submit", onclick: () => this.submit(), disabled: this.submitting },
        this.submitting ? "Submitting…" : "Submit (Ctrl+Enter)"),
      h("div", { class: "button-row" },
        h("button", { class: "no-hand-sample", onclick: () => this.askPass("no_hand") }, "No hand in this sample…"),
        h("button", { class: "skip-sample", onclick: () => this.askPass("skip") }, "Skip…")),
      h("div", { class: "muted legend" }, "proposals: T triangulated from your clicks, F current fit, M MVNet, " +
        `D detector; the number is its confidence (orange: below ${ACCEPT_CONF}, Enter leaves it)`),
      this.sources.map((source) => h("div", { class: source.label.includes("not MANO") ? "badge warn" : "badge" },
        `${SOURCE_LETTER[source.kind]}: ${source.label}`)),
      this.lastSubmission ? h("div", { class: "muted last-submission" },
        `last: sample ${this.lastSubmission.sample_id} → fit job ${this.lastSubmission.fit_job_id ?? "–"}` +
        (this.lastSubmission.failed ? ` failed: ${this.lastSubmission.failed}` : "")) : null,
      h("details", { class: "help" }, h("summary", {}, "Keys (?)"),
        h("table", {}, HELP.map(([k, d]) => h("tr", {}, h("td", {}, h("kbd", {}, k)), h("td", {}, d))))),
    );
    this.renderClock();
  }
}

function labelFor(keypoint) {
  const i = SPARSE.indexOf(keypoint);
  return i >= 0 ? SPARSE_LABELS[i] : String(keypoint);
}

function draftLabel(state) {
  return { unsaved: "draft: unsaved changes", saving: "draft: saving…", saved: "draft: saved",
    error: "draft: not saved yet (retrying)", conflict: "draft: changed in another tab too (keep one above)",
    lost: "draft: saved up to the last save; later changes cannot be saved (sample no longer yours)",
  }[state] || "draft: nothing to save";
}

function confident(p) {
  return p.confidence !== null && p.confidence !== undefined && p.confidence >= ACCEPT_CONF;
}

// "T 0.92": source letter and confidence ("F ?" for a fit, which has none).
function proposalLabel(p) {
  const conf = p.confidence === null || p.confidence === undefined ? "?" : p.confidence.toFixed(2);
  return `${SOURCE_LETTER[p.source] || "?"} ${conf}`;
}
