// The annotate page's input: the pointer on the enlarged view (place, drag or accept a point; paint the mask;
// pan with the right button or Space; the wheel zooms or sizes the brush) and the keys (the list in HELP,
// annotate.js). It turns gestures into the page's editing calls (setClick, acceptProposal, ...); the page keeps
// the state (the drag in progress, the hover point, the keys held), which the drawing reads.
import { inside } from "./annotation.js";
import { isTyping, toast } from "./dom.js";
import { SPARSE } from "./keypoints.js";
import { StrokeRecorder } from "./mask.js";

const HIT_PX = 12; // how close (screen px) a press must be to grab a point
const DRAG_PX = 3; // movement below this is a click, not a drag

export class AnnotateInput {
  /** @param {import("./annotate.js").AnnotatePage} page */
  constructor(page) {
    this.page = page;
  }

  // Listen on the enlarged view's canvas (the keys are the page's: window-wide).
  attach(/** @type {HTMLCanvasElement} */ c) {
    c.addEventListener("pointerdown", (e) => this.pointerdown(e));
    c.addEventListener("pointermove", (e) => this.pointermove(e));
    c.addEventListener("pointerup", (e) => this.pointerup(e));
    c.addEventListener("pointercancel", (e) => this.pointerup(e));
    c.addEventListener("pointerleave", () => { this.setHover(null); this.page.drawing.requestRender(); });
    c.addEventListener("wheel", (e) => this.wheel(e), { passive: false });
    c.addEventListener("contextmenu", (e) => e.preventDefault());
  }

  // The pointer over the enlarged view (the magnifier follows it), or null; the canvas's data-hover says which.
  setHover(/** @type {[number, number] | null} */ point) {
    this.page.hover = point;
    this.page.canvas.dataset.hover = point ? "yes" : "no";
  }

  screenPoint(e) {
    const page = this.page;
    const r = page.canvas.getBoundingClientRect();
    return [e.clientX - r.left, e.clientY - r.top];
  }

  hit(sx, sy) {
    const page = this.page;
    let best = null, bestD = HIT_PX;
    const consider = (k, x, y, kind) => {
      if (x === null || y === null) return;
      const [px, py] = page.vp.toScreen(x, y);
      const d = Math.hypot(px - sx, py - sy);
      if (d < bestD) { bestD = d; best = { keypoint: k, kind, x, y }; }
    };
    for (const [k, c] of page.annotation.clicks.get(page.view.id)) consider(k, c.x, c.y, "click");
    for (const [k, p] of page.proposals.get(page.view.id)) consider(k, p.x, p.y, "proposal");
    for (const [k, p] of page.alternates.get(page.view.id)) consider(k, p.x, p.y, "alternate");
    return best;
  }

  pointerdown(e) {
    const page = this.page;
    if (!page.task) return;
    page.timer.input();
    page.canvas.focus();
    try {
      page.canvas.setPointerCapture(e.pointerId);
    } catch {
      // synthetic events (tests, benchmarks) have no active pointer to capture
    }
    const [sx, sy] = this.screenPoint(e);
    const pan = e.button === 1 || e.button === 2 || (e.button === 0 && page.keys.has("Space"));
    if (pan) {
      page.drag = { type: "pan", sx, sy };
      return;
    }
    if (e.button !== 0) return;
    const [u, v] = page.vp.toImage(sx, sy);
    if (page.mode === "mask") {
      const layer = page.ensureMask(page.view);
      const value = page.tool === "brush" ? 1 : 0;
      page.drag = { type: "stroke", recorder: new StrokeRecorder(layer), last: [u, v], value, view: page.view };
      this.strokeTo(u, v);
      return;
    }
    const target = this.hit(sx, sy);
    if (target) {
      // Decided on release: a drag moves this point; a click places the current keypoint if it is unset.
      page.drag = { type: "point", keypoint: target.keypoint, from: target.kind, sx, sy, moved: false, u: target.x,
        v: target.y, pressU: u, pressV: v };
    } else {
      const existing = page.annotation.get(page.view.id, page.keypoint);
      const visibility = existing && existing.visibility === "occluded" ? "occluded" : "visible";
      page.drag = { type: "place", keypoint: page.keypoint, sx, sy, u, v, visibility };
    }
    page.drawing.requestRender();
  }

  pointermove(e) {
    const page = this.page;
    if (page.timer) page.timer.input();
    const [sx, sy] = this.screenPoint(e);
    const previous = page.hover;
    // Past the canvas's edge (a drag keeps the pointer captured, so no pointerleave comes): no magnifier there.
    const r = page.canvas.getBoundingClientRect();
    this.setHover(sx >= 0 && sy >= 0 && sx <= r.width && sy <= r.height ? [sx, sy] : null);
    const d = page.drag;
    if (!d) {
      if (page.mode === "mask") page.drawing.requestRender(this.cursorRect(previous), this.cursorRect(page.hover));
      else if (page.view && page.view.image) {
        const before = page.drawing.loupeGeometry(previous), now = page.drawing.loupeGeometry(page.hover);
        page.drawing.requestRender(before && before.rect, now && now.rect);
      }
      return;
    }
    if (d.type === "pan") {
      page.vp.pan(sx - d.sx, sy - d.sy);
      d.sx = sx;
      d.sy = sy;
    } else if (d.type === "stroke") {
      const [u, v] = page.vp.toImage(sx, sy);
      const rect = this.strokeTo(u, v);
      // A stroke redraws only what it changed and where the cursor was and is (measured by bench ui).
      page.drawing.requestRender(rect && this.imageRectOnScreen(rect), this.cursorRect(previous), this.cursorRect(page.hover));
      return;
    } else {
      if (Math.hypot(sx - d.sx, sy - d.sy) > DRAG_PX) d.moved = true;
      [d.u, d.v] = page.vp.toImage(sx, sy);
    }
    page.drawing.requestRender();
  }

  strokeTo(u, v) {
    const page = this.page;
    const d = page.drag;
    const layer = d.view.mask;
    const radius = page.radius / 1; // radius is in image pixels
    const rect = layer.stroke(d.last[0], d.last[1], u, v, radius, d.value);
    d.last = [u, v];
    if (rect) {
      d.view.overlay.refresh(rect);
      d.recorder.add(rect);
    }
    return rect;
  }

  imageRectOnScreen(rect) {
    const page = this.page;
    const [x0, y0] = page.vp.toScreen(rect.x - 0.5, rect.y - 0.5);
    const [x1, y1] = page.vp.toScreen(rect.x + rect.w - 0.5, rect.y + rect.h - 0.5);
    return { x: x0 - 2, y: y0 - 2, w: x1 - x0 + 4, h: y1 - y0 + 4 };
  }

  cursorRect(point) {
    const page = this.page;
    if (!point) return null;
    const r = page.radius * page.vp.scale + 3;
    return { x: point[0] - r, y: point[1] - r, w: 2 * r, h: 2 * r };
  }

  pointerup(e) {
    const page = this.page;
    const d = page.drag;
    page.drag = null;
    if (!d) return;
    if (page.canvas.hasPointerCapture(e.pointerId)) page.canvas.releasePointerCapture(e.pointerId);
    if (d.type === "stroke") {
      const view = d.view;
      const command = d.recorder.finish((rect) => { view.overlay.refresh(rect); page.changed(view.id); });
      if (command) {
        view.maskEdited = true;
        page.history.record({ kind: "mask", ...command, undo: command.undo, redo: command.redo });
        page.timer.mark(d.value ? "brush" : "erase", { view_id: view.id });
        page.changed(view.id);
      }
    } else if (d.type === "place") {
      if (this.placeable(d.u, d.v)) {
        page.setClick(page.view.id, d.keypoint, { x: d.u, y: d.v, visibility: d.visibility }, "click");
        page.advance({ afterClick: true });
      }
    } else if (d.type === "point") {
      // A not-annotated keypoint is unset: a click on another point places it there (docs/ui.md).
      const currentUnset = !page.annotation.placed(page.view.id, page.keypoint);
      if (d.moved && !this.placeable(d.u, d.v)) {
        // dropped outside the image: the point stays where it was
      } else if (d.moved) {
        page.keypoint = d.keypoint;
        const existing = page.annotation.get(page.view.id, d.keypoint);
        const offered = d.from === "proposal" ? page.proposals.get(page.view.id).get(d.keypoint) : null;
        const occluded = existing ? existing.visibility === "occluded" : Boolean(offered && offered.hidden);
        page.setClick(page.view.id, d.keypoint, { x: d.u, y: d.v, visibility: occluded ? "occluded" : "visible" }, "drag");
        if (d.from !== "click") page.advance();
      } else if (d.keypoint !== page.keypoint && currentUnset) {
        if (this.placeable(d.pressU, d.pressV)) {
          page.setClick(page.view.id, page.keypoint, { x: d.pressU, y: d.pressV, visibility: "visible" }, "click");
          page.advance({ afterClick: true });
        }
      } else if (d.from === "proposal" || d.from === "alternate") {
        page.keypoint = d.keypoint;
        page.acceptProposal(d.keypoint, { alternate: d.from === "alternate" });
      } else {
        page.keypoint = d.keypoint;
        page.renderSide();
      }
    }
    page.drawing.requestRender();
  }

  // Whether image point (u, v) lies in the view's image; if not, says so (nothing is placed outside it).
  placeable(u, v) {
    const page = this.page;
    if (inside([u, v], page.view)) return true;
    toast(`outside ${page.view.camera}'s image: nothing placed (click on the image)`, "warn", 2500);
    document.body.dataset.refused = "outside";
    return false;
  }

  wheel(e) {
    const page = this.page;
    e.preventDefault();
    if (!page.task) return;
    page.timer.input();
    if (page.mode === "mask" && !e.ctrlKey) {
      page.setRadius(page.radius * (e.deltaY < 0 ? 1.15 : 1 / 1.15));
      return;
    }
    const [sx, sy] = this.screenPoint(e);
    page.vp.zoomAt(Math.exp(-e.deltaY * 0.0015), sx, sy);
    page.drawing.requestRender();
  }

  keydown(e) {
    const page = this.page;
    if (!page.task || isTyping(e)) return;
    page.timer.input();
    page.keys.add(e.code);
    const ctrl = e.ctrlKey || e.metaKey;
    const key = e.key;
    let handled = true;
    if (ctrl && (key === "z" || key === "Z")) {
      if (e.shiftKey) page.redo(); else page.undo();
    } else if (ctrl && (key === "y" || key === "Y")) {
      page.redo();
    } else if (ctrl && key === "Enter") {
      page.submit({ confirmed: page.asking === "submit" });
    } else if (ctrl) {
      handled = false;
    } else if (key >= "1" && key <= "6") {
      page.pick(SPARSE[Number(key) - 1]);
    } else if (key === "Escape" && page.asking) {
      page.closeAsk();
    } else if (key === "x" || key === "X") {
      page.toggleNoHand();
    } else if (key === "Escape") {
      // Keys back to the view from whatever has the focus (a button, the list); a drag in progress ends.
      page.drag = null;
      if (document.activeElement && document.activeElement !== page.canvas) /** @type {HTMLElement} */ (document.activeElement).blur();
      page.canvas.focus();
      page.side.querySelector(".help").removeAttribute("open");
      page.drawing.requestRender();
    } else if (key === "Tab") {
      page.justPlaced = null;
      page.selectView((page.viewIndex + (e.shiftKey ? page.views.length - 1 : 1)) % page.views.length);
    } else if (key === "a" || key === "A") {
      if (!page.acceptProposal(page.keypoint)) toast("no proposal for this keypoint here", "info", 1500);
    } else if (key === "Enter") {
      page.acceptAllInView();
    } else if (key === "o" || key === "O") {
      page.toggleOccluded();
    } else if (key === "n" || key === "N") {
      page.markNotAnnotated();
    } else if (key === "Delete" || key === "Backspace") {
      page.clearKeypoint();
    } else if (key === "m" || key === "M") {
      page.setMode(page.mode === "mask" ? "points" : "mask");
    } else if (key === "b" || key === "B") {
      page.tool = "brush";
      page.setMode("mask");
    } else if (key === "e" || key === "E") {
      page.tool = "eraser";
      page.setMode("mask");
    } else if (key === "p" || key === "P") {
      page.setMode("points");
    } else if (key === "[") {
      page.setRadius(page.radius / 1.25);
    } else if (key === "]") {
      page.setRadius(page.radius * 1.25);
    } else if (key === "h" || key === "H") {
      page.showMask = !page.showMask;
      page.publish();
      page.timer.mark("toggle");
      page.drawing.requestRender();
      page.drawing.buildThumbs();
    } else if (key === "0") {
      // The hand; pressed again (already there), the whole image.
      const before = [page.vp.scale, page.vp.ox, page.vp.oy];
      page.zoom.fitView();
      if (Math.abs(before[0] - page.vp.scale) < 1e-9 && Math.abs(before[1] - page.vp.ox) < 1e-6) page.zoom.fitView({ whole: true });
      page.drawing.requestRender();
    } else if (key === "+" || key === "=") {
      page.zoom.zoomCentre(1.25);
    } else if (key === "-") {
      page.zoom.zoomCentre(0.8);
    } else if (key === "?") {
      page.side.querySelector(".help").toggleAttribute("open");
    } else if (key === " ") {
      // Space + drag pans; keep the page from scrolling.
    } else {
      handled = false;
    }
    if (handled) e.preventDefault();
  }
}
