// The annotate page's zoom and pan of the enlarged view: open a view on the hand (its points, else its mask), the
// whole image with 0 pressed again, zoom at the centre (+ / -), and each view's own zoom kept while the annotator
// moves between views. The Viewport (viewport.js) is the page's `vp`; this module decides where it looks.
import { fitCanvas } from "./dom.js";

// A view opens on the hand with the working copy's pixels at most this many screen px wide (more is visibly
// blocky; zooming in further loads the full-resolution pixels), unless the whole image already shows larger.
const OPEN_MAX_PX = 2;

export class AnnotateZoom {
  /** @param {import("./annotate.js").AnnotatePage} page */
  constructor(page) {
    this.page = page;
    /** @type {Map<string, {scale: number, ox: number, oy: number, minScale: number}>} "sample/view" -> its zoom and pan */
    this.kept = new Map();
  }

  zoomCentre(factor) {
    const page = this.page;
    const r = page.canvas.getBoundingClientRect();
    page.vp.zoomAt(factor, r.width / 2, r.height / 2);
    page.drawing.requestRender();
  }

  // Fit the view to the hand (its clicks and proposals, else its automatic mask), or with whole=true (or no
  // hand found) to the whole image.
  fitView({ whole = false } = {}) {
    const page = this.page;
    if (!page.task) return;
    const { width, height } = fitCanvas(page.canvas);
    const view = page.view;
    const box = whole ? null : this.handBox(view);
    const wholeScale = Math.min((width - 16) / view.width, (height - 16) / view.height);
    if (box) {
      page.vp.fitRect(...box, width, height, 8);
      // No closer than OPEN_MAX_PX screen px per working-copy pixel (unless the whole image shows larger):
      // zoomed further, a 640 px copy opened at 483 % looked blocky. The hand stays centred.
      const copyWidth = view.image ? view.image.width : view.width;
      const most = Math.max(OPEN_MAX_PX * copyWidth / view.width, 1.25 * wholeScale);
      if (page.vp.scale > most) {
        const cx = (box[0] + box[2]) / 2, cy = (box[1] + box[3]) / 2;
        page.vp.scale = most;
        page.vp.ox = width / 2 - (cx + 0.5) * most;
        page.vp.oy = height / 2 - (cy + 0.5) * most;
        page.vp.minScale = most / 8;
      }
      // No blank beyond the image's edge: a hand at the edge once opened as a strip of arm beside empty canvas.
      page.vp.keepInside(view.width, view.height, width, height);
    } else {
      page.vp.fit(view.width, view.height, width, height);
    }
    page.vp.minScale = Math.min(page.vp.minScale, Math.min(width / view.width, height / view.height) / 2);
  }

  // The image rectangle [x0, y0, x1, y1] around the hand in a view, with a margin; null if nothing shows it.
  handBox(view, margin = 0.35, minFraction = 0.2) {
    const page = this.page;
    const xs = [], ys = [];
    // Only points inside the image: a source's projection off the image once opened a view on a strip of arm
    // at its edge.
    const add = (x, y) => {
      if (Number.isFinite(x) && Number.isFinite(y) && x >= 0 && y >= 0 && x <= view.width && y <= view.height) {
        xs.push(x);
        ys.push(y);
      }
    };
    for (const c of page.annotation.clicks.get(view.id).values()) add(c.x, c.y);
    for (const p of (page.proposals ? page.proposals.get(view.id) : new Map()).values()) add(p.x, p.y);
    for (const source of page.sources || []) for (const p of source.views[String(view.id)] || []) if (p) add(p[0], p[1]);
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

  zoomKey(view = this.page.view) {
    const page = this.page;
    return `${page.task.sample_id}/${view.id}`;
  }

  keepZoom() {
    const page = this.page;
    if (!page.task || !page.view) return;
    const { scale, ox, oy, minScale } = page.vp;
    this.kept.set(this.zoomKey(), { scale, ox, oy, minScale });
  }

  restoreZoom() {
    const page = this.page;
    const kept = this.kept.get(this.zoomKey());
    if (kept) Object.assign(page.vp, kept);
    else this.fitView();
  }
}
