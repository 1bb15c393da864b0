// The annotate page's drawing: the enlarged view (image, mask, epipolar curves, points and proposals, the
// magnifier beside the cursor, the brush) redrawn once per frame, whole or only the rectangles that changed;
// and the thumbnails of every view. It reads the page's state and never changes the annotation.
import { fill, fitCanvas, h, toast } from "./dom.js";
import { marker, segment } from "./draw.js";
import { epipolarCurve } from "./geometry.js";
import { loadFullImage, needsFullImage } from "./images.js";
import { colorOf, SPARSE, SPARSE_LABELS } from "./keypoints.js";
import { unionRect } from "./mask.js";
import { Viewport } from "./viewport.js";

const LOUPE_R = 56; // the magnifier's radius, screen px
const LOUPE_OFFSET = 80; // its centre from the cursor, screen px (up and right, flipped near the edges)
const LOUPE_ZOOM = 4; // times the view's zoom ...
const LOUPE_MAX_PX = 24; // ... up to this many screen px per image pixel
export const SOURCE_LETTER = { triangulated: "T", fit: "F", mvnet: "M", detector: "D" };
// Enter accepts only proposals at least this confident; the others are ringed orange for a look (A takes
// one anyway). A fit's projection has no confidence: it is always left for a look.
export const ACCEPT_CONF = 0.6;

/** @typedef {{x: number, y: number, source: string, confidence: number | null, hidden?: boolean}} Proposal */

export function labelFor(/** @type {number} */ keypoint) {
  const i = SPARSE.indexOf(keypoint);
  return i >= 0 ? SPARSE_LABELS[i] : String(keypoint);
}

export function confident(/** @type {Proposal} */ p) {
  return p.confidence !== null && p.confidence !== undefined && p.confidence >= ACCEPT_CONF;
}

// "T 0.92": source letter and confidence ("F ?" for a fit, which has none).
export function proposalLabel(/** @type {Proposal} */ p) {
  const conf = p.confidence === null || p.confidence === undefined ? "?" : p.confidence.toFixed(2);
  return `${SOURCE_LETTER[p.source] || "?"} ${conf}`;
}

export class AnnotateDrawing {
  /** @param {import("./annotate.js").AnnotatePage} page */
  constructor(page) {
    this.page = page;
    /** @type {{scale: number, ox: number, oy: number} | null} the zoom last written to the canvas's data-* */
    this.published = null;
  }

  // The enlarged view's zoom and pan as data-* attributes of its canvas (read by the browser tests and `bench ui`):
  // an image point (u, v) shows at ((u + 0.5) * data-scale + data-ox, (v + 0.5) * data-scale + data-oy), CSS px
  // from the canvas's corner. Written whenever a redraw is asked for, so after every change of the viewport.
  publishViewport() {
    const { vp, canvas } = this.page;
    const p = this.published;
    if (p && p.scale === vp.scale && p.ox === vp.ox && p.oy === vp.oy) return; // a stroke's redraws write nothing
    this.published = { scale: vp.scale, ox: vp.ox, oy: vp.oy };
    canvas.dataset.scale = String(vp.scale);
    canvas.dataset.ox = String(vp.ox);
    canvas.dataset.oy = String(vp.oy);
  }

  // Schedule a redraw for the next frame: of the whole view (no rectangles given), or only of the given
  // screen rectangles (null entries are skipped); a full request wins over partial ones.
  requestRender(...rects) {
    const page = this.page;
    this.publishViewport();
    if (rects.length === 0) page.dirty = "all";
    else if (page.dirty !== "all") for (const r of rects) if (r) page.dirty = unionRect(page.dirty, r);
    if (page.frame) return;
    page.frame = requestAnimationFrame(() => { page.frame = null; this.renderNow(); });
  }

  // Draw what is pending now (the whole view with force); a scheduled frame is then not needed.
  renderNow(force = false) {
    const page = this.page;
    this.publishViewport();
    if (page.frame) { cancelAnimationFrame(page.frame); page.frame = null; }
    const pending = force ? "all" : page.dirty;
    page.dirty = null;
    if (!page.task || !pending) return;
    const dirty = pending === "all" ? null : pending;
    const view = page.view;
    const { width, height, dpr } = fitCanvas(page.canvas);
    const ctx = page.canvas.getContext("2d");
    ctx.save();
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    if (dirty) {
      ctx.beginPath();
      ctx.rect(Math.floor(dirty.x), Math.floor(dirty.y), Math.ceil(dirty.w) + 1, Math.ceil(dirty.h) + 1);
      ctx.clip();
    }
    ctx.fillStyle = "#1b1e24";
    ctx.fillRect(0, 0, width, height);
    page.vp.apply(ctx, dpr);
    ctx.imageSmoothingEnabled = page.vp.scale < 3;
    const image = this.pixelsOf(view, dpr);
    if (image) ctx.drawImage(image, 0, 0, view.width, view.height);  // a working-width copy: full-resolution units
    // Points mode shows the mask's outline only, so the skin under it stays visible.
    if (page.showMask && view.overlay) ctx.drawImage(page.mode === "points" ? view.overlay.outline() : view.overlay.canvas, 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    if (!view.image) {
      ctx.fillStyle = "#9aa0ab";
      ctx.font = "14px system-ui, sans-serif";
      ctx.fillText(`loading ${view.camera}…`, 16, 24);
    }
    const curves = page.mode === "points" && !page.annotation.get(view.id, page.keypoint) ? this.drawEpipolar(ctx, view) : 0;
    page.canvas.dataset.epipolarCurves = String(curves);
    this.drawPoints(ctx, view, page.vp, { labels: true, selected: page.keypoint });
    const target = page.target();
    const tc = target.viewId === view.id ? page.annotation.get(view.id, target.keypoint) : null;
    if (tc && tc.x !== null && target.justPlaced) {
      // The point O and N will change, when it is not the picked one: a white ring around it.
      const [tx, ty] = page.vp.toScreen(tc.x, tc.y);
      ctx.save();
      ctx.strokeStyle = "#fff";
      ctx.lineWidth = 1.5;
      ctx.setLineDash([2, 2]);
      ctx.beginPath();
      ctx.arc(tx, ty, 14, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.restore();
    }
    if (page.mode === "points" && page.hover && view.image && !page.drag) this.drawLoupe(ctx, view, dpr);
    if (page.mode === "mask" && page.hover) {
      ctx.save();
      ctx.strokeStyle = page.tool === "brush" ? "#4cc9f0" : "#ff6b6b";
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.arc(page.hover[0], page.hover[1], page.radius * page.vp.scale, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.restore();
    }
    ctx.restore();
    if (dirty) return;
    page.hud.textContent = `${view.camera} · ${view.width}×${view.height} · ${Math.round(page.vp.scale * 100)}% · ` +
      (page.mode === "mask" ? `mask: ${page.tool} r=${Math.round(page.radius)} px` : `points: ${labelFor(page.keypoint)}` +
        ` · O/N: ${labelFor(target.keypoint)}${target.justPlaced ? " (just placed)" : ""}`);
  }

  // The pixels to draw a view with: its working-width copy, or once zoomed past that copy's own pixels, the
  // full-resolution original (loaded the first time it is needed, then kept for the view).
  pixelsOf(view, dpr) {
    const page = this.page;
    if (!view.fullImage && !view.fullLoading && needsFullImage(view, page.vp.scale, dpr)) {
      const task = page.task;
      view.fullLoading = loadFullImage(page.api, view).then((bitmap) => {
        view.fullImage = bitmap;
        if (page.task === task && page.view === view) this.requestRender();
      }).catch((error) => {
        toast(`full-resolution ${view.camera} did not load: ${error.message}`, "warn", 4000);
      });
    }
    return view.fullImage || view.image;
  }

  // The magnifier: up to LOUPE_ZOOM times the view's zoom around the cursor, in a circle beside it (clear of
  // the finger that points), with a crosshair on the pixel a click would place.
  loupeGeometry(point = this.page.hover) {
    const page = this.page;
    if (!point) return null;
    const r = page.canvas.getBoundingClientRect();
    const [x, y] = point;
    const cx = x + (x + LOUPE_OFFSET + LOUPE_R > r.width ? -LOUPE_OFFSET : LOUPE_OFFSET);
    const cy = y + (y - LOUPE_OFFSET - LOUPE_R < 0 ? LOUPE_OFFSET : -LOUPE_OFFSET);
    return { x, y, cx, cy, rect: { x: cx - LOUPE_R - 3, y: cy - LOUPE_R - 3, w: 2 * LOUPE_R + 6, h: 2 * LOUPE_R + 6 } };
  }

  drawLoupe(ctx, view, dpr) {
    const page = this.page;
    const g = this.loupeGeometry();
    const [u, v] = page.vp.toImage(g.x, g.y);
    // LOUPE_ZOOM times the view's zoom, but no more than LOUPE_MAX_PX screen px per image pixel (at least 1.5x).
    const scale = Math.min(page.vp.scale * LOUPE_ZOOM, Math.max(page.vp.scale * 1.5, LOUPE_MAX_PX));
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
    if (page.showMask && view.overlay) ctx.drawImage(view.overlay.outline(), 0, 0);
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
    page.loupe = { cx: g.cx, cy: g.cy, u, v, zoom: scale / page.vp.scale };
  }

  // While the picked keypoint is being placed here: the epipolar curve of each view where it was placed by
  // hand (the point lies on all of them; lens distortion bends them slightly).
  drawEpipolar(ctx, view) {
    const page = this.page;
    const camTo = page.cameras.get(view.id);
    if (!camTo) return 0;
    let curves = 0;
    ctx.save();
    ctx.strokeStyle = colorOf(page.keypoint);
    ctx.globalAlpha = 0.7;
    ctx.lineWidth = 1;
    ctx.setLineDash([6, 4]);
    for (const other of page.views) {
      const c = other.id === view.id ? null : page.annotation.get(other.id, page.keypoint);
      if (!c || c.from || c.x === null) continue;
      const curve = epipolarCurve([c.x, c.y], page.cameras.get(other.id), camTo);
      ctx.beginPath();
      curve.forEach(([u, v], i) => {
        const [sx, sy] = page.vp.toScreen(u, v);
        if (i === 0) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy);
      });
      ctx.stroke();
      curves++;
    }
    ctx.restore();
    return curves;
  }

  // Clicks, proposals and the dragged point of one view, on a 2D context in screen units.
  drawPoints(ctx, view, vp, { labels = false, selected = null, r = 6 } = {}) {
    const page = this.page;
    const clicks = page.annotation.clicks.get(view.id);
    const drag = page.drag && view === page.view && (page.drag.type === "place" || page.drag.type === "point")
      ? page.drag : null;
    const pos = (k, c) => (drag && drag.keypoint === k && (drag.type === "place" || drag.moved) ? [drag.u, drag.v] : [c.x, c.y]);
    const wrist = clicks.get(0);
    if (wrist && wrist.x !== null) {
      for (const k of SPARSE.slice(1)) {
        const c = clicks.get(k);
        if (c && c.x !== null) segment(ctx, vp.toScreen(...pos(0, wrist)), vp.toScreen(...pos(k, c)), colorOf(k), 1, [4, 4]);
      }
    }
    for (const [k, p] of page.alternates.get(view.id)) {
      if (drag && drag.keypoint === k) continue;
      const [x, y] = vp.toScreen(p.x, p.y);
      marker(ctx, x, y, k, { style: "alternate", r, label: labels ? proposalLabel(p) : null });
    }
    for (const [k, p] of page.proposals.get(view.id)) {
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
    const page = this.page;
    fill(page.thumbs, ...page.views.map((view, i) => {
      const canvas = h("canvas", { class: "thumb-canvas" });
      const el = h("button", { class: `thumb${i === page.viewIndex ? " active" : ""}`, title: `${view.camera} (Tab)`,
        onclick: () => { page.justPlaced = null; page.selectView(i); } }, canvas, h("span", { class: "thumb-label" }, ""));
      view.thumb = { el, canvas };
      return el;
    }));
    page.views.forEach((_, i) => this.labelThumb(i));
    requestAnimationFrame(() => page.views.forEach((_, i) => this.renderThumb(i)));
  }

  renderThumb(index) {
    const page = this.page;
    const view = page.views[index];
    if (!view || !view.thumb) return;
    const { canvas } = view.thumb;
    const { width, height, dpr } = fitCanvas(canvas);
    const ctx = canvas.getContext("2d");
    const vp = new Viewport().fit(view.width, view.height, width, height, 2);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.fillStyle = "#111";
    ctx.fillRect(0, 0, width, height);
    vp.apply(ctx, dpr);
    if (view.image) ctx.drawImage(view.image, 0, 0, view.width, view.height);  // a working-width copy: full-resolution units
    if (page.showMask && view.overlay) ctx.drawImage(view.overlay.canvas, 0, 0);
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    this.drawPoints(ctx, view, vp, { r: 3 });
    this.labelThumb(index);
  }

  // A thumbnail's label, and its data-* attributes (read by the browser tests): data-view-id, data-camera, data-loaded
  // (its image is in), data-width and data-height (the full-resolution image's, px) and per keypoint k data-k{k} = its status here ("unset", "visible", "occluded", "not_annotated").
  labelThumb(/** @type {number} */ index) {
    const page = this.page;
    const view = page.views[index];
    if (!view || !view.thumb) return;
    const { el } = view.thumb;
    el.dataset.viewId = String(view.id);
    el.dataset.loaded = view.image ? "yes" : "no";
    el.dataset.camera = view.camera;
    el.dataset.width = String(view.width);
    el.dataset.height = String(view.height);
    for (const k of page.annotation.keypoints) el.dataset[`k${k}`] = page.annotation.status(view.id, k);
    // Placed points out of the keypoints; those marked not annotated apart ("· 2 N"): they are decided, not done.
    const done = page.annotation.doneIn(view.id);
    const skipped = page.annotation.notAnnotatedIn(view.id);
    el.querySelector(".thumb-label").textContent =
      `${index + 1} ${view.camera} ${page.noHand.has(view.id) ? "no hand"
        : `${done}/${page.annotation.keypoints.length}${skipped ? ` · ${skipped} N` : ""}`}` +
      `${view.maskEdited ? " ✎" : ""}`;
    el.classList.toggle("complete", done === page.annotation.keypoints.length);
  }
}
