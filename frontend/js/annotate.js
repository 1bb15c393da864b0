// The annotate page: 8 views in a grid plus one enlarged with zoom and pan; click wrist and fingertips
// per view (keys pick the keypoint, mark it occluded or not annotated), accept or drag proposals, correct
// the automatic mask with brush and eraser, undo and redo, submit; the next task is prefetched.
// AnnotatePage holds the annotation and its edits; the queue lifecycle is queue.js's, the pointer and keys
// annotate_input.js's, the zoom annotate_zoom.js's, the drawing and magnifier annotate_drawing.js's, the side
// panel annotate_panel.js's (frontend/README.md).
import { Annotation, inside, proposals as computeProposals, triangulateClicked } from "./annotation.js";
import { AnnotateDrawing, ACCEPT_CONF, confident } from "./annotate_drawing.js";
import { AnnotateInput } from "./annotate_input.js";
import { AnnotatePanel, draftLabel } from "./annotate_panel.js";
import { AnnotateZoom } from "./annotate_zoom.js";
import { paths } from "./api.js";
import { fill, h, toast } from "./dom.js";
import { projectPoint } from "./geometry.js";
import { History } from "./history.js";
import { decodeMask, loadView } from "./images.js";
import { SPARSE } from "./keypoints.js";
import { MaskLayer, MaskOverlay } from "./mask.js";
import { QueueController, QueuePage } from "./queue.js";
import { ActionTimer } from "./timing.js";
import { Viewport } from "./viewport.js";

const MIN_CONF = 0.3; // a source's points below this confidence are not offered (annotation.js proposals())
const ALTERNATE_PX = 2; // a detector point this close to the proposal shown is not drawn again

export async function mountAnnotate(root, ctx) {
  const page = new AnnotatePage(root, ctx);
  await page.start();
  return page;
}

export class AnnotatePage extends QueuePage {
  constructor(root, { api, user }) {
    super();
    this.api = api;
    this.root = root;
    this.queue = new QueueController(api, "annotate", user.id, {
      prepare: (task, options) => this.prepare(task, options), show: (prepared) => this.show(prepared),
      empty: () => this.showEmpty(), retaken: (sampleId) => this.leaseRetaken(sampleId),
      lost: (sampleId, error) => this.leaseLost(sampleId, error), snapshot: () => this.draftBody(),
      draftStatus: (state, detail) => this.draftStatus(state, detail),
      draftConflict: (theirs) => this.draftConflict(theirs) });
    this.history = new History();
    this.history.onchange = () => this.renderSide();
    this.vp = new Viewport();
    this.mode = "points";
    this.tool = "brush";
    this.radius = 12;
    this.showMask = true;
    this.autoAdvance = true;
    this.pending = 0;
    // State that input (annotate_input.js) writes and drawing (annotate_drawing.js) reads:
    /** @type {any} the press in progress: {type: "pan" | "stroke" | "point" | "place", ...}, or null */
    this.drag = null;
    /** @type {[number, number] | null} the pointer over the enlarged view, screen px */
    this.hover = null;
    /** @type {number | null} the animation frame a redraw waits for */
    this.frame = null;
    /** @type {"all" | {x: number, y: number, w: number, h: number} | null} what the next redraw covers */
    this.dirty = null;
    /** @type {{cx: number, cy: number, u: number, v: number, zoom: number} | null} the magnifier last drawn */
    this.loupe = null;
    this.keys = new Set();
    this.metrics = { shown: [] };
    this.failedFits = []; // the fits that failed on this person's submissions (GET /api/annotate/fit-failures)
    this.noHand = new Set();
    this.input = new AnnotateInput(this);
    this.zoom = new AnnotateZoom(this);
    this.drawing = new AnnotateDrawing(this);
    this.panel = new AnnotatePanel(this);
    this.build();
    this.onKey = (e) => this.input.keydown(e);
    this.onKeyUp = (e) => this.keys.delete(e.code);
    this.onResize = () => { this.zoom.fitView(); this.drawing.requestRender(); };
    // The clock counts working time: between inputs, not across a pause of more than 30 s or a hidden tab.
    this.onVisibility = () => { if (document.hidden && this.timer) this.timer.pause(); };
    document.addEventListener("visibilitychange", this.onVisibility);
    window.addEventListener("keydown", this.onKey);
    window.addEventListener("keyup", this.onKeyUp);
    window.addEventListener("resize", this.onResize);
    this.clock = setInterval(() => this.panel.renderClock(), 1000);
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
    this.input.attach(this.canvas);
  }

  // The side panel, drawn again after each change (annotate_panel.js).
  renderSide() {
    this.panel.render();
  }

  // Zoom and drawing, as the tests and `bench ui` call them.
  fitView(options = {}) {
    this.zoom.fitView(options);
  }

  renderNow(force = false) {
    this.drawing.renderNow(force);
  }

  unmount() {
    window.removeEventListener("keydown", this.onKey);
    window.removeEventListener("keyup", this.onKeyUp);
    window.removeEventListener("resize", this.onResize);
    document.removeEventListener("visibilitychange", this.onVisibility);
    clearInterval(this.clock);
    clearTimeout(this.fitWatch);
    this.unpublish(["viewIndex", "keypoint", "mode", "tool", "radius", "showMask", "pointsPlaced", "noHand"]);
    this.queue.unmount();
  }

  // --- tasks --------------------------------------------------------------------------------------

  // A task's proposals and images. The task shown next (eager=false) is ready as soon as its first view
  // is: the others fill in while the annotator works on it. A prefetched task is loaded whole.
  async prepare(task, { eager = true } = {}) {
    const t0 = performance.now();
    const loads = task.views.map((view) => loadView(this.api, view));
    const proposals = this.api.get(paths.proposals(task.sample_id));
    const draft = this.drafts.load(task.sample_id);
    const ready = eager ? await Promise.all(loads) : [await loads[0]];
    const views = task.views.map((view, i) => ({ ...view, image: null, maskImage: null, ...(ready[i] || {}) }));
    return { task, proposals: await proposals, draft: await draft, views, loads, loadMs: performance.now() - t0 };
  }

  showEmpty() {
    this.root.querySelector(".annotate-page").classList.add("empty");
    fill(this.side, h("div", { class: "empty-note" }, h("h2", {}, "Nothing to annotate"),
      h("p", {}, "The annotation queue is empty. This page looks again every 10 s."),
      h("button", { onclick: () => this.queue.loadNext() }, "Look again")));
    fill(this.thumbs, );
    this.hud.textContent = "";
    const ctx = this.canvas.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, this.canvas.width, this.canvas.height);
    document.body.dataset.ready = "annotate-empty";
  }

  show(prepared) {
    const t0 = performance.now();
    this.root.querySelector(".annotate-page").classList.remove("empty");
    const { task, proposals, views } = prepared;
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
        if (i === this.viewIndex) this.drawing.requestRender();
        this.drawing.renderThumb(i);
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
    this.drawing.buildThumbs();
    this.zoom.fitView();
    this.drawing.renderNow(true);
    this.renderSide();
    this.metrics.shown.push({ sample_id: task.sample_id, show_ms: performance.now() - t0, load_ms: prepared.loadMs,
      at_ms: performance.now() });
    this.decodeRestLater(task.sample_id);
    document.body.dataset.draft = prepared.draft ? String(prepared.draft.revision) : "none";
    document.body.dataset.ready = "annotate";
    document.body.dataset.sample = String(task.sample_id);
    document.body.dataset.sequenceId = String(task.sequence_id);
    document.body.dataset.frameIndex = String(task.frame_index);
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
    this.drawing.renderThumb(this.views.findIndex((v) => v.id === viewId));
    this.drawing.requestRender();
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
      this.drawing.requestRender();
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
    this.drawing.requestRender();
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
      this.drawing.renderThumb(this.views.indexOf(view));
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
    const masks = this.editedMasks();
    return { lease_token: this.task.lease_token, submission_id: this.submissionId,
      time_spent_s: Math.round(this.timer.spentSeconds() * 1000) / 1000, clicks, masks,
      view_index: this.viewIndex, keypoint: this.keypoint, no_hand_views: [...this.noHand] };
  }

  // The masks corrected by hand, as the draft and the submission carry them (run-length encoded, full resolution).
  editedMasks() {
    return this.views.filter((v) => v.maskEdited && v.mask)
      .map((v) => ({ view_id: v.id, width: v.width, height: v.height, rle: v.mask.toRLE() }));
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
        this.drawing.renderNow(true);
        this.renderSide();
      } }, "Take the other"));
    this.banner.hidden = false;
    document.body.dataset.draftConflict = String(theirs.revision);
  }

  leaseRetaken(sampleId) {
    this.hideBanner();
    toast(`your lease on sample ${sampleId} had lapsed: taken again, nothing lost`, "info", 3000);
  }

  leaseLost(sampleId, error) {
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

  giveUp() {
    this.hideBanner();
    return this.queue.giveUp();
  }

  // --- tools and views (what input, annotate_input.js, calls) --------------------------------------

  setRadius(r) {
    this.radius = Math.max(1, Math.min(200, r));
    this.drawing.requestRender();
    this.renderSide();
  }

  setMode(mode) {
    this.mode = mode;
    this.canvas.classList.toggle("mask-mode", mode === "mask");
    this.drawing.requestRender();
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
    this.zoom.keepZoom();
    this.viewIndex = index;
    this.decodeMask(this.view);
    this.timer.mark("view", { view_id: this.view.id });
    this.keypoint = this.annotation.firstUnset(this.view.id) ??
      this.annotation.firstUnset(this.view.id, -1, { placedToo: true }) ?? this.keypoint;
    this.zoom.restoreZoom();
    this.drawing.requestRender();
    for (const [i, el] of [...this.thumbs.children].entries()) el.classList.toggle("active", i === index);
    this.renderSide();
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
      const body = { kind, reason: reason.trim(), lease_token: task.lease_token };
      const result = await this.queue.postLeased(paths.skip(task.sample_id), body, task.sample_id);
      this.closeAsk();
      this.queue.finished(task.sample_id);
      toast(kind === "no_hand" ? `sample ${task.sample_id}: no hand (${result.state})`
        : `skipped sample ${task.sample_id}: it goes to someone else`, "ok", 2500);
      this.queue.current = null;
      await this.queue.loadNext();
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
    const masks = this.editedMasks();
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
      const result = await this.queue.postLeased(paths.submissions(task.sample_id), body, task.sample_id);
      this.queue.finished(task.sample_id); // the server deleted the draft with the submission
      this.queue.logActivity({
        context: "annotate", sample_id: task.sample_id, submission_id: result.submission_id,
        time_spent_s: body.time_spent_s, actions: this.timer.actions.slice(0, 20000),
      });
      this.lastSubmission = { sample_id: task.sample_id, fit_job_id: result.fit_job_id, clicks: body.clicks.length,
        masks: masks.length, submission: result.id };
      this.watchFit(result.id);
      toast(`submitted sample ${task.sample_id}: ${masks.length} mask(s), fit job ${result.fit_job_id ?? "–"} queued`,
        "ok", 2500);
      this.submitting = false;
      await this.queue.loadNext();
    } catch (error) {
      this.submitting = false;
      toast(`submit failed: ${error.message}`, "error", 8000);
      this.renderSide();
    }
  }

  // --- data-* hooks -------------------------------------------------------------------------------

  // The page's state as data-* attributes of <body> (what the browser tests read, not the page's fields):
  // data-sample, data-sequence-id and data-frame-index (set in show), data-view-index (the view enlarged,
  // 0-based), data-keypoint (the one picked), data-mode ("points" | "mask"), data-tool ("brush" | "eraser"),
  // data-radius (the brush's, image px), data-show-mask ("yes" | "no"), data-points-placed (over every view),
  // data-no-hand (the ids of the views marked). Each thumbnail carries its view's (drawing.labelThumb), the canvas
  // its zoom (drawing.publishViewport) and whether the pointer is over it (data-hover, input.setHover).
  publish() {
    const d = document.body.dataset;
    d.viewIndex = String(this.viewIndex);
    d.keypoint = String(this.keypoint);
    d.mode = this.mode;
    d.tool = this.tool;
    d.radius = String(this.radius);
    d.showMask = this.showMask ? "yes" : "no";
    d.pointsPlaced = String(this.views.reduce((n, v) => n + this.annotation.doneIn(v.id), 0));
    d.noHand = [...this.noHand].join(" ");
  }
}

