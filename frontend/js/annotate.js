// The annotate page: 8 views in a grid plus one enlarged with zoom and pan; click wrist and fingertips
// per view (keys pick the keypoint, mark it occluded or not annotated), accept or drag proposals, correct
// the automatic mask with brush and eraser, undo and redo, submit; the next task is prefetched.
import { Annotation, proposals as computeProposals } from "./annotation.js";
import { fitCanvas, fmt, h, isTyping, toast, fill } from "./dom.js";
import { marker, segment } from "./draw.js";
import { History } from "./history.js";
import { decodeMask, loadView } from "./images.js";
import { colorOf, SPARSE, SPARSE_LABELS } from "./keypoints.js";
import { LeaseKeeper } from "./lease.js";
import { MaskLayer, MaskOverlay, StrokeRecorder, unionRect } from "./mask.js";
import { ActionTimer } from "./timing.js";
import { Viewport } from "./viewport.js";

const HIT_PX = 12; // how close (screen px) a press must be to grab a point
const DRAG_PX = 3; // movement below this is a click, not a drag
const SOURCE_LETTER = { triangulated: "T", fit: "F", mvnet: "M", detector: "D" };
const HELP = [
  ["1 … 6", "pick wrist, thumb, index, middle, ring, pinky"],
  ["click", "place the keypoint (then the next one is picked)"],
  ["drag", "move a point or a proposal"],
  ["A / Enter", "accept the proposal of this keypoint / of all keypoints in this view"],
  ["O", "toggle occluded (position is a best guess)"],
  ["N", "mark not annotated in this view"],
  ["Del", "clear this keypoint in this view"],
  ["Tab / Shift+Tab", "next / previous view (or click a thumbnail)"],
  ["M", "mask mode on / off; B brush, E eraser"],
  ["[ ] / wheel", "brush size (wheel in mask mode; Ctrl+wheel zooms)"],
  ["wheel, right-drag", "zoom, pan (Space+drag pans too); 0 fits the view"],
  ["H", "hide / show the mask"],
  ["Ctrl+Z / Ctrl+Shift+Z", "undo / redo"],
  ["Ctrl+Enter", "submit and show the next task"],
];

export async function mountAnnotate(root, ctx) {
  const page = new AnnotatePage(root, ctx);
  await page.start();
  return page;
}

class AnnotatePage {
  constructor(root, { api }) {
    this.api = api;
    this.root = root;
    this.leases = new LeaseKeeper(api, "annotate");
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
    this.metrics = { shown: [] };
    this.build();
    this.onKey = (e) => this.keydown(e);
    this.onKeyUp = (e) => this.keys.delete(e.code);
    this.onResize = () => { this.fitView(); this.requestRender(); };
    window.addEventListener("keydown", this.onKey);
    window.addEventListener("keyup", this.onKeyUp);
    window.addEventListener("resize", this.onResize);
    this.clock = setInterval(() => this.renderClock(), 1000);
  }

  build() {
    this.canvas = h("canvas", { class: "main-canvas", "aria-label": "enlarged view", tabindex: "0" });
    this.thumbs = h("div", { class: "thumbs", "aria-label": "views" });
    this.hud = h("div", { class: "hud" });
    this.side = h("aside", { class: "side" });
    this.root.append(h("div", { class: "annotate-page" }, this.thumbs,
      h("section", { class: "stage" }, this.canvas, this.hud), this.side));
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
    clearInterval(this.clock);
    clearTimeout(this.emptyTimer);
    // The prefetched sample goes back to the queue; the one on screen stays ours until its lease expires.
    if (this.prepared) this.leases.drop(this.prepared.task.sample_id, true);
    this.leases.dropAll(false);
  }

  async releaseAll() {
    await this.leases.dropAll(true);
  }

  // --- tasks --------------------------------------------------------------------------------------

  // A task's proposals and images. The task shown next (eager=false) is ready as soon as its first view
  // is: the others fill in while the annotator works on it. A prefetched task is loaded whole.
  async prepare(task, { eager = true } = {}) {
    const t0 = performance.now();
    this.leases.hold(task);
    const loads = task.views.map((view) => loadView(this.api, view));
    const proposals = this.api.get(`/api/annotate/samples/${task.sample_id}/proposals`);
    const ready = eager ? await Promise.all(loads) : [await loads[0]];
    const views = task.views.map((view, i) => ({ ...view, image: null, maskImage: null, ...(ready[i] || {}) }));
    return { task, proposals: await proposals, views, loads, loadMs: performance.now() - t0 };
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
    if (!prepared) {
      const task = await this.api.post("/api/annotate/next");
      if (!task) return this.showEmpty();
      prepared = await this.prepare(task, { eager: false });
    }
    this.show(prepared);
    this.prefetch();
  }

  prefetch() {
    const current = this.task.sample_id;
    this.preparing = (async () => {
      const task = await this.api.post("/api/annotate/prefetch", { current_sample_id: current });
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
    for (const c of proposals.previous_clicks) {
      if (this.annotation.clicks.has(c.view_id) && this.annotation.keypoints.includes(c.keypoint)) {
        this.previousClicks = true;
        this.annotation.set(c.view_id, c.keypoint, { x: c.x, y: c.y, visibility: c.visibility });
      }
    }
    this.viewIndex = 0;
    this.keypoint = this.annotation.firstUnset(this.views[0].id) ?? SPARSE[0];
    this.timer = new ActionTimer();
    this.submissionId = crypto.randomUUID();
    this.updateProposals();
    this.history.clear();
    this.buildThumbs();
    this.fitView();
    this.renderNow(true);
    this.renderSide();
    this.metrics.shown.push({ sample_id: task.sample_id, show_ms: performance.now() - t0, load_ms: prepared.loadMs,
      at_ms: performance.now() });
    this.decodeRestLater(task.sample_id);
    document.body.dataset.ready = "annotate";
    document.body.dataset.sample = String(task.sample_id);
  }

  get view() {
    return this.views[this.viewIndex];
  }

  // --- editing ------------------------------------------------------------------------------------

  setClick(viewId, keypoint, value, kind) {
    const previous = this.annotation.set(viewId, keypoint, value);
    const apply = (v) => { this.annotation.set(viewId, keypoint, v); this.changed(viewId); };
    this.history.record({ kind, undo: () => apply(previous), redo: () => apply(value) });
    this.timer.mark(kind, { view_id: viewId, keypoint });
    this.changed(viewId);
  }

  changed(viewId) {
    this.updateProposals();
    this.renderThumb(this.views.findIndex((v) => v.id === viewId));
    this.requestRender();
    this.renderSide();
  }

  updateProposals() {
    this.proposals = computeProposals(this.annotation, this.cameras, this.sources);
  }

  advance() {
    if (!this.autoAdvance) return;
    const next = this.annotation.firstUnset(this.view.id, this.keypoint);
    if (next !== null) {
      this.keypoint = next;
    } else {
      for (let i = 1; i < this.views.length; i++) {
        const idx = (this.viewIndex + i) % this.views.length;
        const k = this.annotation.firstUnset(this.views[idx].id);
        if (k !== null) {
          this.selectView(idx);
          this.keypoint = k;
          break;
        }
      }
    }
    this.renderSide();
  }

  acceptProposal(keypoint, { advance = true } = {}) {
    const p = this.proposals.get(this.view.id).get(keypoint);
    if (!p) return false;
    this.setClick(this.view.id, keypoint, { x: p.x, y: p.y, visibility: "visible" }, "accept");
    if (advance) this.advance();
    return true;
  }

  acceptAllInView() {
    const pending = [...this.proposals.get(this.view.id).keys()];
    for (const k of pending) this.acceptProposal(k, { advance: false });
    if (pending.length === 0) toast("no proposals left in this view", "info", 1500);
    this.advance();
  }

  toggleOccluded() {
    const click = this.annotation.get(this.view.id, this.keypoint);
    if (!click || click.visibility === "not_annotated") {
      const p = this.proposals.get(this.view.id).get(this.keypoint);
      if (!p) return toast("place the keypoint first (its best guess), then mark it occluded", "info", 2500);
      return this.setClick(this.view.id, this.keypoint, { x: p.x, y: p.y, visibility: "occluded" }, "occlude");
    }
    const visibility = click.visibility === "occluded" ? "visible" : "occluded";
    this.setClick(this.view.id, this.keypoint, { ...click, visibility }, "occlude");
  }

  markNotAnnotated() {
    this.setClick(this.view.id, this.keypoint, { x: null, y: null, visibility: "not_annotated" }, "not_annotated");
    this.advance();
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
    return best;
  }

  pointerdown(e) {
    if (!this.task) return;
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
    const [sx, sy] = this.screenPoint(e);
    const previous = this.hover;
    this.hover = [sx, sy];
    const d = this.drag;
    if (!d) {
      if (this.mode === "mask") this.requestRender(this.cursorRect(previous), this.cursorRect(this.hover));
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
      this.setClick(this.view.id, d.keypoint, { x: d.u, y: d.v, visibility: d.visibility }, "click");
      this.advance();
    } else if (d.type === "point") {
      const currentUnset = this.annotation.get(this.view.id, this.keypoint) === null;
      if (d.moved) {
        this.keypoint = d.keypoint;
        const existing = this.annotation.get(this.view.id, d.keypoint);
        const visibility = existing && existing.visibility === "occluded" ? "occluded" : "visible";
        this.setClick(this.view.id, d.keypoint, { x: d.u, y: d.v, visibility }, "drag");
        if (d.from === "proposal") this.advance();
      } else if (d.keypoint !== this.keypoint && currentUnset) {
        this.setClick(this.view.id, this.keypoint, { x: d.pressU, y: d.pressV, visibility: "visible" }, "click");
        this.advance();
      } else if (d.from === "proposal") {
        this.keypoint = d.keypoint;
        this.acceptProposal(d.keypoint);
      } else {
        this.keypoint = d.keypoint;
        this.renderSide();
      }
    }
    this.requestRender();
  }

  wheel(e) {
    e.preventDefault();
    if (!this.task) return;
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
    this.keys.add(e.code);
    const ctrl = e.ctrlKey || e.metaKey;
    const key = e.key;
    let handled = true;
    if (ctrl && (key === "z" || key === "Z")) {
      if (e.shiftKey) this.redo(); else this.undo();
    } else if (ctrl && (key === "y" || key === "Y")) {
      this.redo();
    } else if (ctrl && key === "Enter") {
      this.submit();
    } else if (ctrl) {
      handled = false;
    } else if (key >= "1" && key <= "6") {
      this.keypoint = SPARSE[Number(key) - 1];
      this.requestRender();
      this.renderSide();
    } else if (key === "Tab") {
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
      this.fitView();
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
    const c = this.history.undo();
    if (c) this.timer.mark("undo");
  }

  redo() {
    const c = this.history.redo();
    if (c) this.timer.mark("redo");
  }

  selectView(index) {
    if (index === this.viewIndex) return;
    this.viewIndex = index;
    this.decodeMask(this.view);
    this.timer.mark("view", { view_id: this.view.id });
    this.keypoint = this.annotation.firstUnset(this.view.id) ?? this.keypoint;
    this.fitView();
    this.requestRender();
    for (const [i, el] of [...this.thumbs.children].entries()) el.classList.toggle("active", i === index);
    this.renderSide();
  }

  fitView() {
    if (!this.task) return;
    const { width, height } = fitCanvas(this.canvas);
    this.vp.fit(this.view.width, this.view.height, width, height);
  }

  // --- submit -------------------------------------------------------------------------------------

  async submit() {
    if (!this.task || this.submitting) return;
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
    this.submitting = true;
    this.renderSide();
    try {
      const result = await this.api.post(`/api/annotate/samples/${task.sample_id}/submissions`, body);
      this.leases.drop(task.sample_id, false);
      const log = {
        context: "annotate", sample_id: task.sample_id, submission_id: result.submission_id,
        time_spent_s: body.time_spent_s, actions: this.timer.actions.slice(0, 20000),
      };
      this.api.post("/api/activity", log).catch((error) => toast(`time log not saved: ${error.message}`, "warn"));
      this.lastSubmission = { sample_id: task.sample_id, fit_job_id: result.fit_job_id, clicks: body.clicks.length,
        masks: masks.length };
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
    if (view.image) ctx.drawImage(view.image, 0, 0);
    if (this.showMask && view.overlay) ctx.drawImage(view.overlay.canvas, 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    if (!view.image) {
      ctx.fillStyle = "#9aa0ab";
      ctx.font = "14px system-ui, sans-serif";
      ctx.fillText(`loading ${view.camera}…`, 16, 24);
    }
    this.drawPoints(ctx, view, this.vp, { labels: true, selected: this.keypoint });
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
      (this.mode === "mask" ? `mask: ${this.tool} r=${Math.round(this.radius)} px` : `points: ${labelFor(this.keypoint)}`);
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
    for (const [k, p] of this.proposals.get(view.id)) {
      if (drag && drag.keypoint === k) continue;
      const [x, y] = vp.toScreen(p.x, p.y);
      marker(ctx, x, y, k, { style: "proposal", r, label: labels ? SOURCE_LETTER[p.source] : null,
        selected: labels && selected === k });
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
        onclick: () => this.selectView(i) }, canvas, h("span", { class: "thumb-label" }, ""));
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
    if (view.image) ctx.drawImage(view.image, 0, 0);
    if (this.showMask && view.overlay) ctx.drawImage(view.overlay.canvas, 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    this.drawPoints(ctx, view, vp, { r: 3 });
    const done = this.annotation.doneIn(view.id);
    el.querySelector(".thumb-label").textContent =
      `${index + 1} ${view.camera} ${done}/${this.annotation.keypoints.length}${view.maskEdited ? " ✎" : ""}`;
    el.classList.toggle("complete", done === this.annotation.keypoints.length);
  }

  renderClock() {
    const el = this.side.querySelector(".clock");
    if (!el || !this.task) return;
    const expires = this.leases.expiresAt(this.task.sample_id);
    const left = expires ? Math.max(0, Math.round((expires - Date.now()) / 1000)) : null;
    el.textContent = `time ${fmt(this.timer.spentSeconds(), 0, " s")} · lease ${left === null ? "–" : `${left} s`}`;
  }

  renderSide() {
    if (!this.task || !this.proposals) return;
    const view = this.view;
    const props = this.proposals.get(view.id);
    const rows = SPARSE.map((k, i) => {
      const status = this.annotation.status(view.id, k);
      const p = props.get(k);
      const text = status === "unset" ? (p ? `proposal (${p.source})` : "–") : status.replace("_", " ");
      return h("li", { class: `kp-row${k === this.keypoint ? " current" : ""} status-${status}`,
        onclick: () => { this.keypoint = k; this.requestRender(); this.renderSide(); } },
      h("kbd", {}, String(i + 1)), h("span", { class: "swatch", style: { background: colorOf(k) } }),
      h("span", { class: "kp-name" }, SPARSE_LABELS[i]), h("span", { class: "kp-status" }, text));
    });
    const total = this.views.reduce((n, v) => n + this.annotation.doneIn(v.id), 0);
    const masks = this.views.filter((v) => v.maskEdited).length;
    const t = this.task;
    fill(this.side, 
      h("div", { class: "sample-head" },
        h("h2", {}, `Sample ${t.sample_id}`),
        h("div", { class: "muted" }, `sequence ${t.sequence_id} · frame ${t.frame_index}`),
        h("div", { class: "clock muted" }, "")),
      this.reviewNote ? h("div", { class: "callout" }, h("strong", {}, "Reviewer: "), this.reviewNote) : null,
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
        h("button", { onclick: () => this.acceptAllInView(), disabled: props.size === 0 }, `Accept ${props.size} proposals (Enter)`),
        h("button", { onclick: () => this.toggleOccluded() }, "Occluded (O)"),
        h("button", { onclick: () => this.markNotAnnotated() }, "Not annotated (N)")),
      h("div", { class: "button-row" },
        h("button", { onclick: () => this.undo(), disabled: !this.history.canUndo }, "Undo"),
        h("button", { onclick: () => this.redo(), disabled: !this.history.canRedo }, "Redo")),
      h("div", { class: "totals" }, `${total}/${this.views.length * this.annotation.keypoints.length} keypoints · ${masks} mask(s) corrected`),
      h("button", { class: "primary submit", onclick: () => this.submit(), disabled: this.submitting },
        this.submitting ? "Submitting…" : "Submit (Ctrl+Enter)"),
      h("div", { class: "muted legend" }, "proposals: T triangulated from your clicks, D detector, F current fit, M MVNet"),
      this.sources.map((source) => h("div", { class: source.label.includes("not MANO") ? "badge warn" : "badge" },
        `${SOURCE_LETTER[source.kind]}: ${source.label}`)),
      this.lastSubmission ? h("div", { class: "muted" },
        `last: sample ${this.lastSubmission.sample_id} → fit job ${this.lastSubmission.fit_job_id ?? "–"}`) : null,
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
