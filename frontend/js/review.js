// The review page: the fit's outline, wireframe, keypoints and skeleton over every view (toggleable), with
// per-view IoU and residuals; the sample's 3D scene in viser's client; accept / reject / needs annotation /
// discard with one key (a reason for reject and annotation); the next sample is prefetched and drawn ahead.
import { fitCanvas, fmt, h, handSide, isTyping, toast, fill } from "./dom.js";
import { marker, segment } from "./draw.js";
import { loadViews } from "./images.js";
import { colorOf, fingerOf, FINGER_COLORS } from "./keypoints.js";
import { contourEdges, decodeMesh, projectVertices } from "./mesh.js";
import { QueueController, QueuePage } from "./queue.js";
import { ActionTimer } from "./timing.js";
import { Viewport } from "./viewport.js";
import { paths } from "./api.js";

const QUICK_REASONS = {
  reject: ["hand model badly misaligned", "wrong global pose (flipped or mirrored)", "fingers tangled or implausible",
    "capture unusable (blur, hand not visible)", "object occludes too much"],
  annotate: ["a fingertip is on the wrong finger", "the wrist is off", "the silhouette misses fingers",
    "the mask includes background or the forearm", "occluded tips guessed badly"],
};
const LAYERS = [
  ["outline", "O", "outline"], ["silhouette", "S", "silhouette"], ["wireframe", "W", "wireframe"],
  ["keypoints", "K", "keypoints and skeleton"], ["clicks", "C", "annotators' clicks and residuals"],
  ["mvnet", "P", "MVNet prediction"],
];
const HELP = [
  ["A", "accept"],
  ["D", "discard: not good enough, the sample waits for the next round's networks (fits from predictions only)"],
  ["R / N", "reject / needs annotation: then 1-5 a common reason (while the note is empty) or type one, " +
    "Enter sends, Esc cancels"],
  ["O S W K C P", "outline, silhouette, wireframe, keypoints, annotators' clicks, MVNet"],
  ["1 … 8", "enlarge a view"],
  ["Esc", "back to the grid; gives the keys back to the page (from the 3D view too)"],
  ["Z", "crop to the hand / whole images"],
  ["V", "show / hide the 3D view"],
  ["F", "3D view over the image grid / back beside it (or drag its lower edge to resize it)"],
  ["?", "open / close this list"],
];
const IOU_LOW = 0.5;
const REASON_MAX = 2000; // the server's limit on a decision's reason (schemas.tasks.DecisionCreate)
const VIEWER_DELAY_MS = 350;
const SHOW_3D_KEY = "handloop.show3d";
let softwareGL = null;

// Whether WebGL runs in software here (SwiftShader, llvmpipe): viser's client then costs seconds of the
// page's CPU per sample, so the 3D view starts closed (the reviewer's own choice is remembered).
function softwareWebGL() {
  if (softwareGL === null) {
    try {
      const gl = document.createElement("canvas").getContext("webgl");
      const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
      const renderer = gl ? String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER)) : "none";
      softwareGL = !gl || /swiftshader|llvmpipe|software/i.test(renderer);
      const lose = gl && gl.getExtension("WEBGL_lose_context");
      if (lose) lose.loseContext();
    } catch {
      softwareGL = true;
    }
  }
  return softwareGL;
}

function initialShow3d() {
  const saved = localStorage.getItem(SHOW_3D_KEY);
  return saved === null ? !softwareWebGL() : saved === "1";
}
const RESIDUAL_HIGH_PX = 8;

export async function mountReview(root, ctx) {
  const page = new ReviewPage(root, ctx);
  await page.start();
  return page;
}

class ReviewPage extends QueuePage {
  constructor(root, { api, user }) {
    super();
    this.api = api;
    this.root = root;
    // The reviewer's note in progress (decision picked, reason typed) survives a reload like annotations.
    this.queue = new QueueController(api, "review", user.id, {
      prepare: (task) => this.prepare(task), show: (prepared) => this.show(prepared),
      empty: () => this.showEmpty(), retaken: () => this.hideLeaseBanner(),
      lost: (sampleId, error) => this.leaseLost(sampleId, error), snapshot: () => this.draftBody(),
      // Warm the next 3D scene (built once on the server, then from the browser's cache).
      prefetched: (prepared) => { if (this.show3d) fetch(prepared.overlay.scene_path, { priority: "low" }).catch(() => null); },
      draftStatus: (state, detail) => {
        document.body.dataset.draftState = state;
        if (state === "saved") document.body.dataset.draftSaved = String(detail.revision);
      } });
    this.layers = { outline: true, silhouette: false, wireframe: false, keypoints: true, clicks: true, mvnet: false };
    this.show3d = initialShow3d();
    this.large3d = false; // the 3D view over the image grid (F) rather than in the side panel
    this.cropToHand = true;
    this.focus = null;
    this.reason = null;
    this.metrics = { decisions: [] };
    this.build();
    this.onKey = (e) => { this.firstAct(); this.keydown(e); };
    this.onResize = () => this.renderViews();
    this.onAct = () => this.firstAct();
    window.addEventListener("keydown", this.onKey);
    for (const kind of ["pointerdown", "pointermove", "wheel"]) root.addEventListener(kind, this.onAct, { passive: true });
    window.addEventListener("resize", this.onResize);
    this.clock = setInterval(() => this.renderClock(), 1000);
  }

  build() {
    this.banner = h("div", { class: "fit-banner" });
    this.grid = h("div", { class: "review-grid" });
    this.side = h("aside", { class: "side review-side" });
    this.viewer = h("div", { class: "viewer3d" });
    this.leaseBanner = h("div", { class: "lease-banner", role: "alert", hidden: true });
    this.root.append(h("div", { class: "review-page" },
      h("section", { class: "review-main" }, this.leaseBanner, this.banner, this.grid), this.side));
  }

  unmount() {
    window.removeEventListener("keydown", this.onKey);
    window.removeEventListener("resize", this.onResize);
    clearInterval(this.clock);
    clearTimeout(this.viewerTimer);
    delete document.body.dataset.viewer3d;
    this.unpublish(["reason", "focus", "crop", "layers", "show3d", "clock"]);
    this.queue.unmount();
  }

  // --- tasks --------------------------------------------------------------------------------------

  async prepare(task) {
    const [overlay, views, draft] = await Promise.all([
      this.api.get(paths.overlay(task.sample_id)),
      loadViews(this.api, task, { masks: false }),
      this.drafts.load(task.sample_id),
    ]);
    const mesh = overlay.mesh ? decodeMesh(overlay.mesh) : null;
    const byId = new Map(overlay.views.map((v) => [v.view_id, v]));
    const prepared = views.map((v) => {
      const info = byId.get(v.id);
      const projected = mesh ? projectVertices(mesh.vertices, info) : null;
      return { ...v, info, projected, contour: projected ? contourEdges(projected, mesh) : null,
        crop: handCrop(projected, info) };
    });
    return { task, overlay, mesh, views: prepared, draft };
  }

  showEmpty() {
    fill(this.grid, h("div", { class: "empty-note" }, h("h2", {}, "Nothing to review"),
      h("p", {}, "No fitted sample is waiting for verification. This page looks again every 10 s."),
      h("button", { onclick: () => this.queue.loadNext() }, "Look again")));
    this.banner.textContent = "";
    fill(this.side, );
    document.body.dataset.ready = "review-empty";
  }

  show(prepared) {
    this.timer = new ActionTimer();
    // The clock runs from the reviewer's first act (a key, the pointer), not from when the page opened; right
    // after a decision the reviewer is acting already, so the next sample's clock starts at once.
    this.clockWaits = !this.justDecided;
    this.justDecided = false;
    this.reason = null;
    this.focus = null;
    this.hideLeaseBanner();
    delete document.body.dataset.draftState;
    delete document.body.dataset.draftSaved;
    // A decision is the reviewer's own: a note someone left on a lapsed lease (`left_by`) is not shown to the next
    // reviewer, who judges the fit unanchored (docs/ui.md); on the annotate page such work does travel.
    const draft = prepared.draft && !prepared.draft.left_by ? prepared.draft : null;
    this.drafts.track(prepared.task.sample_id, draft ? draft.revision : 0);
    if (draft && draft.payload.decision && draft.payload.decision !== "accept") {
      this.reason = { kind: draft.payload.decision, text: draft.payload.reason };
      this.timer.carriedMs = draft.payload.time_spent_s * 1000;
      window.__handloop.marks.draftRestored = performance.now();
    }
    document.body.dataset.draft = draft ? String(draft.revision) : "none";
    this.buildGrid();
    this.renderViews();
    this.renderSide();
    document.body.dataset.ready = "review";
    document.body.dataset.sample = String(prepared.task.sample_id);
  }

  // --- decisions ----------------------------------------------------------------------------------

  async decide(decision, reason = "") {
    if (!this.current || this.deciding) return;
    const keyAt = this.keyAt ?? performance.now();
    this.keyAt = null;
    const { task } = this.current;
    this.deciding = true;
    this.release3d();
    try {
      const result = await this.queue.postLeased(paths.decision(task.sample_id),
        { decision, reason, lease_token: task.lease_token }, task.sample_id);
      this.queue.finished(task.sample_id); // the server deleted the draft with the decision
      const decidedAt = performance.now();
      this.timer.mark("decide");
      this.queue.logActivity({ context: "review", sample_id: task.sample_id, decision_id: result.id,
        time_spent_s: Math.round(this.spentSeconds() * 1000) / 1000, actions: this.timer.actions });
      // A gold label (known right) does not move: the decision was recorded as the reviewer's answer to it.
      const effect = result.recorded_as === "gold_answer" ? " (a gold check: recorded as your answer; the label stays)"
        : result.stream ? ` (joins D as ${result.stream})` : decision === "discard" && result.state === "fitted"
          ? " (waits for the next round's fit)" : "";
      toast(`sample ${task.sample_id}: ${decision}${effect}`, "ok", 2000);
      this.deciding = false;
      this.justDecided = true;
      const prefetched = Boolean(this.prepared);
      await this.queue.loadNext();
      const drawnAt = performance.now();
      await new Promise((resolve) => requestAnimationFrame(() => resolve())); // the frame that paints it
      this.metrics.decisions.push({ sample_id: task.sample_id, decision, decided_ms: decidedAt - keyAt,
        drawn_ms: drawnAt - keyAt, next_shown_ms: performance.now() - keyAt, prefetched,
        next_sample_id: this.current ? this.current.task.sample_id : null });
    } catch (error) {
      this.deciding = false;
      this.render3d(); // the same sample's 3D view back
      toast(`decision failed: ${error.message}`, "error", 8000);
    }
  }

  // The 3D view goes at the decision: viser's client is a same-origin iframe, so its rendering (in software
  // where there is no GPU) runs on this page's main thread and held up the decision's answer and the next
  // sample's drawing (1.1-1.3 s instead of 0.06-0.1 s in `bench ui` at load 13-17). render3d starts it again
  // for the next sample, VIEWER_DELAY_MS after that sample is shown.
  release3d() {
    if (!this.viewer.querySelector("iframe")) return;
    clearTimeout(this.viewerTimer);
    this.viewerSample = null;
    fill(this.viewer, h("div", { class: "muted viewer-wait" }, "3D view loading…"));
  }

  // Whether a digit key picks a common reason (true) or is typed into the note (false).
  digitsPick() {
    const text = this.reason.text; // as typed: a space after a picked reason is the start of one's own words
    return text.trim() === "" || QUICK_REASONS[this.reason.kind].includes(text);
  }

  pickReason(index) {
    this.reason.text = QUICK_REASONS[this.reason.kind][index];
    this.timer.mark("reason");
    this.drafts.changed();
    this.renderSide();
    const input = this.side.querySelector(".reason-input");
    if (input) {
      input.focus();
      input.setSelectionRange(input.value.length, input.value.length); // typing goes on after the reason
    }
  }

  cancelReason() {
    this.reason = null;
    this.drafts.changed();
    this.renderSide();
    if (document.activeElement && document.activeElement !== document.body) /** @type {HTMLElement} */ (document.activeElement).blur();
  }

  openReason(kind) {
    this.reason = { kind, text: "" };
    this.drafts.changed();
    this.renderSide();
    const input = this.side.querySelector(".reason-input");
    if (input) input.focus();
  }

  // --- leases -------------------------------------------------------------------------------------

  // The note in progress as a draft (PUT .../draft): the decision picked and the reason typed so far.
  draftBody() {
    if (!this.current) return null;
    return { lease_token: this.current.task.lease_token, decision: this.reason ? this.reason.kind : null,
      reason: this.reason ? this.reason.text.slice(0, REASON_MAX) : "",
      time_spent_s: Math.round(this.spentSeconds() * 1000) / 1000 };
  }

  leaseLost(sampleId, error) {
    fill(this.leaseBanner, h("strong", {}, `Sample ${sampleId} is no longer yours. `), h("span", {}, `${error.message}.`),
      h("button", { class: "primary next-task", onclick: () => this.giveUp() }, "Take the next sample"));
    this.leaseBanner.hidden = false;
    document.body.dataset.lease = "lost";
  }

  hideLeaseBanner() {
    this.leaseBanner.hidden = true;
    fill(this.leaseBanner, );
    delete document.body.dataset.lease;
  }

  giveUp() {
    this.hideLeaseBanner();
    return this.queue.giveUp();
  }

  // --- keys ---------------------------------------------------------------------------------------

  keydown(e) {
    if (!this.current) return;
    const key = e.key;
    if (this.reason) {
      if (key === "Escape") {
        this.cancelReason();
        e.preventDefault();
      } else if (key === "Enter") {
        e.preventDefault();
        const text = this.reason.text.trim();
        if (!text) return toast("give a reason (type it, or press 1-5 for a common one)", "warn", 2500);
        this.keyAt = performance.now();
        this.decide(this.reason.kind, text);
      } else if (key >= "1" && key <= "5" && !e.ctrlKey && !e.metaKey && !e.altKey && this.digitsPick()) {
        // A digit picks a common reason while the note holds none of the reviewer's own words (empty, or a
        // common reason picked before); once they have typed, digits are typed like any other character.
        e.preventDefault();
        this.pickReason(Number(key) - 1);
      }
      return;
    }
    if (key === "Escape") {
      // Esc always brings the keys back to the page (out of a text box, the 3D view's iframe, a button).
      if (document.activeElement && document.activeElement !== document.body) /** @type {HTMLElement} */ (document.activeElement).blur();
      window.focus();
    }
    if (isTyping(e) || e.ctrlKey || e.metaKey || e.altKey) return;
    const lower = key.toLowerCase();
    let handled = true;
    if (lower === "a") {
      this.keyAt = performance.now();
      this.decide("accept");
    } else if (lower === "d") {
      this.discard();
    } else if (lower === "r") {
      this.openReason("reject");
    } else if (lower === "n") {
      this.openReason("annotate");
    } else if (key >= "1" && key <= "8") {
      this.setFocus(Number(key) - 1);
    } else if (key === "Escape") {
      if (this.large3d) this.toggleLarge3d();
      this.setFocus(null);
    } else if (lower === "z") {
      this.cropToHand = !this.cropToHand;
      this.timer.mark("zoom");
      this.renderViews();
      this.renderSide();
    } else if (lower === "v") {
      this.toggle3d();
    } else if (lower === "f") {
      this.toggleLarge3d();
    } else if (key === "?") {
      this.helpOpen = !this.helpOpen;
      this.renderSide();
    } else {
      const layer = LAYERS.find(([, k]) => k.toLowerCase() === lower);
      if (layer) {
        this.layers[layer[0]] = !this.layers[layer[0]];
        this.timer.mark("toggle");
        this.renderViews();
        this.renderSide();
      } else {
        handled = false;
      }
    }
    if (handled) e.preventDefault();
  }

  setFocus(index) {
    this.focus = index !== null && index < this.current.views.length && index !== this.focus ? index : null;
    this.grid.classList.toggle("focused", this.focus !== null);
    for (const [i, card] of [...this.grid.children].entries()) card.classList.toggle("focus", i === this.focus);
    this.timer.mark("view");
    this.renderViews();
  }

  // --- rendering ----------------------------------------------------------------------------------

  buildGrid() {
    const { overlay } = this.current;
    const model = overlay.hand_model;
    fill(this.banner, 
      h("span", { class: model.stand_in ? "badge warn" : "badge" }, `Fit ${overlay.fit_id}: ${model.label}`),
      h("span", { class: "muted" }, ` · mean IoU ${fmt(overlay.fit.mean_iou, 2)} · mean residual ` +
        residualBanner(overlay.fit)),
      overlay.mesh ? null : h("span", { class: "badge warn" }, overlay.mesh_note || "no mesh"));
    this.grid.classList.remove("focused");
    fill(this.grid, ...this.current.views.map((view, i) => {
      const canvas = h("canvas", { class: "review-canvas" });
      const iou = view.info.iou, res = view.info.mean_residual_px;
      const badge = h("div", { class: "view-badge" },
        h("span", {}, `${i + 1} ${view.camera}`),
        h("span", { class: iou !== null && iou < IOU_LOW ? "bad" : "" }, `IoU ${fmt(iou, 2)}`),
        h("span", { class: res !== null && res > RESIDUAL_HIGH_PX ? "bad" : "" }, `res ${fmt(res, 1, " px")}`));
      const card = h("div", { class: "view-card", onclick: () => this.setFocus(i) }, canvas, badge);
      view.card = { card, canvas };
      return card;
    }));
  }

  renderViews() {
    if (!this.current) return;
    this.publish();
    for (const view of this.current.views) this.renderView(view);
  }

  renderView(view) {
    const { canvas } = view.card;
    const { width, height, dpr } = fitCanvas(canvas);
    if (width < 2 || height < 2) return;
    const ctx = canvas.getContext("2d");
    const vp = this.cropToHand && view.crop
      ? new Viewport().fitRect(...view.crop, width, height)
      : new Viewport().fit(view.width, view.height, width, height, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.fillStyle = "#111";
    ctx.fillRect(0, 0, width, height);
    vp.apply(ctx, dpr);
    ctx.drawImage(view.image, 0, 0, view.width, view.height);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    const { mesh } = this.current;
    const info = view.info;
    const L = this.layers;
    const s = (p) => vp.toScreen(p[0], p[1]);
    if (mesh && view.projected) {
      const px = view.projected;
      const pt = (i) => vp.toScreen(px[2 * i], px[2 * i + 1]);
      if (L.silhouette) {
        // Every triangle wound the same way, so one nonzero fill is the union (the silhouette).
        ctx.beginPath();
        const f = mesh.faces;
        for (let t = 0; t < f.length; t += 3) {
          let [a, b, c] = [pt(f[t]), pt(f[t + 1]), pt(f[t + 2])];
          if ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]) < 0) [b, c] = [c, b];
          ctx.moveTo(a[0], a[1]);
          ctx.lineTo(b[0], b[1]);
          ctx.lineTo(c[0], c[1]);
          ctx.closePath();
        }
        ctx.fillStyle = "rgba(255, 190, 60, 0.35)";
        ctx.fill("nonzero");
      }
      if (L.wireframe) {
        ctx.beginPath();
        const e = mesh.edges;
        for (let i = 0; i < e.length; i += 2) {
          const a = pt(e[i]), b = pt(e[i + 1]);
          ctx.moveTo(a[0], a[1]);
          ctx.lineTo(b[0], b[1]);
        }
        ctx.strokeStyle = "rgba(120, 220, 255, 0.35)";
        ctx.lineWidth = 0.6;
        ctx.stroke();
      }
      if (L.outline) {
        ctx.beginPath();
        for (const edge of view.contour) {
          const a = pt(mesh.edges[2 * edge]), b = pt(mesh.edges[2 * edge + 1]);
          ctx.moveTo(a[0], a[1]);
          ctx.lineTo(b[0], b[1]);
        }
        ctx.strokeStyle = "rgba(255, 214, 10, 0.95)";
        ctx.lineWidth = 1.4;
        ctx.stroke();
      }
    }
    const fitPx = info.fit_keypoints_px;
    if (L.clicks) {
      for (const c of info.clicks) {
        if (c.x === null) continue;
        const p = s([c.x, c.y]);
        const f = fitPx[c.keypoint];
        if (f) segment(ctx, p, s(f), "#ff4d6d", 1.5, [3, 2]);
        // An accepted proposal is drawn as a proposal (dashed ring): the fit landing on it proves little.
        const style = c.from_proposal ? "proposal" : c.visibility === "occluded" ? "occluded" : "solid";
        marker(ctx, p[0], p[1], c.keypoint, { style, r: 4 });
      }
    }
    if (L.mvnet && info.prediction_keypoints_px) {
      for (const [k, p] of info.prediction_keypoints_px.entries()) {
        if (!p) continue;
        const q = s(p);
        ctx.save();
        ctx.fillStyle = "#fff";
        ctx.strokeStyle = colorOf(k);
        ctx.translate(q[0], q[1]);
        ctx.rotate(Math.PI / 4);
        ctx.fillRect(-3, -3, 6, 6);
        ctx.strokeRect(-3, -3, 6, 6);
        ctx.restore();
      }
    }
    if (L.keypoints) {
      for (const [a, b] of this.current.overlay.skeleton_edges) {
        if (fitPx[a] && fitPx[b]) segment(ctx, s(fitPx[a]), s(fitPx[b]), FINGER_COLORS[fingerOf(b)], 2);
      }
      for (const [k, p] of fitPx.entries()) if (p) marker(ctx, ...s(p), k, { style: "fit", r: 3 });
    }
  }

  toggle3d() {
    this.show3d = !this.show3d;
    if (!this.show3d && this.large3d) {
      this.large3d = false;
      this.placeViewer();
    }
    localStorage.setItem(SHOW_3D_KEY, this.show3d ? "1" : "0");
    this.timer.mark("toggle");
    this.renderSide();
  }

  // The 3D view over the image grid (the side panel stays) or back in the side panel: only its place on the
  // screen changes (CSS), the iframe stays where it is in the page, so the scene and its camera are kept (an
  // iframe moved in the document would reload).
  toggleLarge3d() {
    this.large3d = !this.large3d;
    if (this.large3d && !this.show3d) this.toggle3d();
    this.timer.mark("toggle");
    this.placeViewer();
  }

  placeViewer() {
    this.viewer.classList.toggle("large", this.large3d);
    document.body.dataset.viewer3d = this.large3d ? "large" : "side";
    for (const button of this.viewer.querySelectorAll(".viewer-size")) {
      button.textContent = this.large3d ? "Back beside the images (F)" : "Over the image grid (F)";
    }
  }

  viewerUrl() {
    const { overlay } = this.current;
    // The server picks the start (the rig's own up, from the cameras' side): a real rig's world is often y-down.
    const q = (v) => v.map((x) => x.toFixed(3)).join(",");
    return `/viewer/?playbackPath=${encodeURIComponent(overlay.scene_path)}` +
      `&initialCameraPosition=${q(overlay.scene_eye)}&initialCameraLookAt=${q(overlay.scene_look_at)}` +
      `&initialCameraUp=${q(overlay.scene_up)}`;
  }

  render3d() {
    if (!this.show3d || !this.current) {
      clearTimeout(this.viewerTimer);
      fill(this.viewer, h("button", { class: "viewer-open", onclick: () => this.toggle3d() }, "Show the 3D view (V)"), softwareWebGL() ? h("div", { class: "muted" },
        "Closed by default here: this browser renders WebGL in software, which would slow the page down.") : null);
      this.viewerSample = null;
      return this.viewer;
    }
    const sample = this.current.task.sample_id;
    if (this.viewerSample !== sample) {
      // The iframe (viser's client, its recording, WebGL) starts a moment after the sample is shown, so it
      // does not compete with drawing the views or with a quick decision.
      this.viewerSample = sample;
      clearTimeout(this.viewerTimer);
      fill(this.viewer, h("div", { class: "muted viewer-wait" }, "3D view loading…"));
      const url = this.viewerUrl();
      this.viewerTimer = setTimeout(() => {
        if (this.viewerSample !== sample) return;
        const frame = h("iframe", { class: "viewer-frame", title: "3D view of this sample (viser)", src: url,
          allowfullscreen: true });
        frame.addEventListener("load", () => { this.listenInFrame(frame); quietSoftwareNotice(frame); });
        fill(this.viewer, h("div", { class: "viewer-bar" },
          h("button", { class: "small viewer-size", onclick: () => this.toggleLarge3d() }, ""),
          h("button", { class: "small viewer-fullscreen", onclick: () => frame.requestFullscreen().catch((error) =>
            toast(`full screen refused: ${error.message}`, "warn")) }, "Full screen"),
          softwareWebGL() ? h("span", { class: "muted software-note", title: "viser's own notice about it is hidden" },
            "software WebGL: slow") : null), frame);
        this.placeViewer();
      }, VIEWER_DELAY_MS);
    }
    return this.viewer;
  }

  // The 3D view keeps the keyboard focus after a drag in it: listen there too (same origin), so every
  // review key still works; Esc hands the focus back to the page.
  listenInFrame(frame) {
    let win;
    try {
      win = frame.contentWindow;
      win.addEventListener("keydown", (e) => {
        if (e.key === "Escape") {
          frame.blur();
          window.focus();
        }
        this.onKey(e);
        if (e.defaultPrevented) e.stopPropagation();
      }, true);
    } catch {
      // another origin: nothing to listen to (the viewer is served by this backend, so not expected)
    }
  }

  firstAct() {
    if (!this.clockWaits || !this.timer) return;
    this.clockWaits = false;
    const carried = this.timer.carriedMs;
    this.timer.start();
    this.timer.carriedMs = carried;
    this.publish();
    this.renderClock();
  }

  // The page's state as data-* attributes of <body> (what the browser tests read, not the page's fields):
  // data-sample (set in show), data-reason (the decision whose reason is asked for: "reject" | "annotate"; absent
  // when none), data-focus (the view enlarged, 0-based; absent: the grid), data-crop ("hand" | "whole"),
  // data-layers (those shown, space-separated), data-show3d ("yes" | "no"), data-clock ("waits" until the first
  // act, then "runs").
  publish() {
    const d = document.body.dataset;
    if (this.reason) d.reason = this.reason.kind; else delete d.reason;
    if (this.focus !== null) d.focus = String(this.focus); else delete d.focus;
    d.crop = this.cropToHand ? "hand" : "whole";
    d.layers = Object.keys(this.layers).filter((name) => this.layers[name]).join(" ");
    d.show3d = this.show3d ? "yes" : "no";
    d.clock = this.clockWaits ? "waits" : "runs";
  }

  // Active seconds on this sample so far (0 until the first act).
  spentSeconds() {
    return this.clockWaits ? this.timer.carriedMs / 1000 : this.timer.spentSeconds();
  }

  renderClock() {
    const el = this.side.querySelector(".clock");
    if (!el || !this.current) return;
    el.textContent = this.clockWaits ? "time starts when you act" : `time ${fmt(this.timer.spentSeconds(), 0, " s")}`;
  }

  renderSide() {
    if (!this.current) return;
    this.publish();
    const { task, overlay } = this.current;
    const fit = overlay.fit;
    const heur = fit.heuristic;
    const pred = overlay.prediction;
    fill(this.side, 
      h("div", { class: "sample-head" },
        h("h2", {}, `Sample ${task.sample_id}`),
        h("div", { class: "muted" }, `${task.sequence ?? `sequence ${task.sequence_id}`} · frame ${task.frame_index} · fit ${overlay.fit_id}`),
        handSide(task.side),
        h("div", { class: "clock muted" }, "")),
      h("div", { class: overlay.hand_model.stand_in ? "callout warn" : "callout" }, overlay.hand_model.label),
      h("dl", { class: "facts" },
        h("dt", {}, "fitted from"), h("dd", {}, fit.source),
        h("dt", {}, "mean IoU"), h("dd", {}, fmt(fit.mean_iou, 3)),
        ...residualFacts(fit),
        pred ? [h("dt", {}, "MVNet"), h("dd", {}, `${pred.mvnet_version}, confidence ${fmt(pred.mean_confidence, 2)}`)] : null,
        heur ? [h("dt", {}, "heuristic"), h("dd", {}, heurText(heur))] : null),
      this.reason ? this.reasonBox() : h("div", { class: "decide" },
        h("button", { class: "accept", onclick: () => { this.keyAt = performance.now(); this.decide("accept"); } }, "Accept (A)"),
        h("button", { class: "reject", onclick: () => this.openReason("reject") }, "Reject (R)"),
        h("button", { class: "annotate", onclick: () => this.openReason("annotate") }, "Needs annotation (N)"),
        this.canDiscard() ? h("button", { class: "discard", onclick: () => this.discard() }, "Discard (D)") : null),
      h("div", { class: "layers" }, LAYERS.map(([name, key, label]) => h("label", {},
        h("input", { type: "checkbox", checked: this.layers[name], onchange: (e) => {
          this.layers[name] = e.target.checked;
          this.renderViews();
        } }), ` ${label} (${key})`))),
      pred ? null : h("div", { class: "muted mvnet-note" },
        "MVNet layer (P) empty: no MVNet prediction exists for this sample (this fit was made from " +
        (fit.source === "detector" ? "the detector's keypoints)." : "clicks).")),
      h("div", { class: "muted" }, `1-8 enlarge a view, Esc back · Z ${this.cropToHand ? "whole images" : "zoom to the hand"} · V 3D view`),
      // The Keys list above the 3D view, which takes the rest of the panel: opened, it is in sight.
      h("details", { class: "help", open: this.helpOpen }, h("summary", {}, "Keys (?)"),
        h("table", {}, HELP.map(([k, d]) => h("tr", {}, h("td", {}, h("kbd", {}, k)), h("td", {}, d))))),
      this.render3d(),
    );
    this.renderClock();
  }

  // A fit that used annotators' clicks is not discarded: back in the pool, the next round would fit predictions
  // instead of their clicks (the server refuses it too).
  canDiscard() {
    return Boolean(this.current && this.current.task.fit && !this.current.task.fit.from_annotation);
  }

  discard() {
    if (!this.canDiscard()) {
      return toast("this fit used annotators' clicks: accept it, send it back (N) or reject it (R)", "warn", 3000);
    }
    this.keyAt = performance.now();
    this.decide("discard");
  }

  reasonBox() {
    const kind = this.reason.kind;
    const count = h("div", { class: "reason-count muted" });
    const counted = () => {
      const n = this.reason.text.length;
      count.textContent = `${n} / ${REASON_MAX} characters`;
      count.classList.toggle("bad", n >= REASON_MAX);
    };
    const input = h("input", { class: "reason-input", type: "text", maxlength: REASON_MAX,
      placeholder: "reason (Enter to send, Esc to cancel)", value: this.reason.text,
      oninput: (e) => { this.reason.text = e.target.value; this.drafts.changed(); counted(); } });
    counted();
    return h("div", { class: `reason-box ${kind}` },
      h("h3", {}, kind === "reject" ? "Reject: why?" : "Needs annotation: what is wrong?"),
      h("ol", {}, QUICK_REASONS[kind].map((r, i) => h("li", { onclick: () => this.pickReason(i) },
        h("kbd", {}, String(i + 1)), ` ${r}`))),
      h("div", { class: "muted reason-hint" }, "1-5 pick a common reason while the note is empty; " +
        "once you type, digits are part of the note."),
      input, count,
      h("div", { class: "button-row" },
        h("button", { class: "primary", onclick: () => {
          if (!this.reason.text.trim()) return toast("give a reason", "warn", 2000);
          this.keyAt = performance.now();
          this.decide(kind, this.reason.text.trim());
        } }, "Send (Enter)"),
        h("button", { onclick: () => this.cancelReason() }, "Cancel (Esc)")));
  }
}

// The image region around the fitted hand (its projected mesh, else its keypoints), with a margin, so the
// grid shows the hand large; null when nothing projects into the view.
function handCrop(projected, info, margin = 0.35, minFraction = 0.2) {
  const xs = [], ys = [];
  if (projected) {
    for (let i = 0; i < projected.length; i += 2) {
      if (Number.isFinite(projected[i])) { xs.push(projected[i]); ys.push(projected[i + 1]); }
    }
  } else {
    for (const p of info.fit_keypoints_px) if (p) { xs.push(p[0]); ys.push(p[1]); }
  }
  if (xs.length === 0) return null;
  let x0 = Math.max(-0.5, Math.min(...xs)), x1 = Math.min(info.width - 0.5, Math.max(...xs));
  let y0 = Math.max(-0.5, Math.min(...ys)), y1 = Math.min(info.height - 0.5, Math.max(...ys));
  if (x1 <= x0 || y1 <= y0) return null;
  const w = Math.max((x1 - x0) * (1 + 2 * margin), info.width * minFraction);
  const hh = Math.max((y1 - y0) * (1 + 2 * margin), info.height * minFraction);
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  return [cx - w / 2, cy - hh / 2, cx + w / 2, cy + hh / 2];
}

// The heuristic's verdict in words. The cross-estimator checks (workers/tasks/cross_checks.py) accept where the
// paper's criteria failed: MVNet's fit agreed with the detector's lift, or the pre-annotation's fit with MVNet.
const CROSS_CHECKS = {
  "mvnet+detector": "passed against the detector's lift",
  "detector+mvnet": "the pre-annotation's fit, which MVNet agreed with, was accepted",
};
function heurText(heur) {
  if (!heur.accepted) return `failed: ${(heur.failed || []).join(", ")}`;
  return CROSS_CHECKS[heur.estimator] ?? "passed";
}

// The fit's residuals, the points placed by hand apart from those accepted from proposals (a fit lands near
// the proposal it came from: counted together, the accepted ones would make the fit look better than the
// evidence).
function residualFacts(fit) {
  const split = fit.residual_by_origin;
  if (!split || !split.accepted.n) {
    const against = fit.residual_reference ? ` vs ${fit.residual_reference}` : "";
    return [h("dt", {}, "residual"), h("dd", { class: "residual-clicked" },
      `${fmt(fit.mean_residual_px, 1)} px mean, ${fmt(fit.max_residual_px, 1)} max${against}`)];
  }
  const line = (g, what) => `${fmt(g.mean_px, 1)} px mean, ${fmt(g.max_px, 1)} max over ${g.n} ${what}`;
  return [
    h("dt", {}, "residual, clicked"), h("dd", { class: "residual-clicked" },
      split.clicked.n ? line(split.clicked, "points placed by hand") : "none placed by hand"),
    h("dt", {}, "residual, accepted"), h("dd", { class: "residual-accepted" },
      line(split.accepted, "accepted proposals")),
  ];
}

function residualBanner(fit) {
  const split = fit.residual_by_origin;
  if (!split || !split.accepted.n) return `${fmt(fit.mean_residual_px, 1, " px")} (vs ${fit.residual_reference ?? "–"})`;
  return `${fmt(split.clicked.mean_px, 1, " px")} vs clicks, ${fmt(split.accepted.mean_px, 1, " px")} vs accepted proposals`;
}

// viser's client shows its own "Software WebGL rendering detected" notification over most of a small view; the
// page says it already (next to the view's buttons), so that notification is hidden as soon as it appears. The
// client is same-origin (served by this backend), so its document can be reached; others are left alone.
function quietSoftwareNotice(frame) {
  let doc;
  try {
    doc = frame.contentDocument;
  } catch {
    return;
  }
  if (!doc || !doc.body) return;
  const hide = () => {
    for (const el of doc.querySelectorAll("[class*='Notification-root'], [role='alert']")) {
      if (/software\s+(webgl\s+)?rendering/i.test(el.textContent || "") && el.style.display !== "none") {
        el.style.display = "none";
        frame.dataset.softwareNotice = "hidden";
      }
    }
  };
  hide();
  new MutationObserver(hide).observe(doc.body, { childList: true, subtree: true });
}
