// One sample's annotation in progress: per view and sparse keypoint a click {x, y, visibility, from?} or
// nothing (`from`: the proposal source it was accepted from; absent when placed by hand), and the
// proposals offered where nothing is set yet, each with its source and confidence.
import { projectPoint, triangulate } from "./geometry.js";

// A triangulated point's confidence falls linearly with its worst reprojection error in the clicked views:
// 1 at 0 px, 0 at this many px (the outlier threshold of triangulate()).
export const TRIANGULATION_ZERO_CONF_PX = 12;

export class Annotation {
  constructor(viewIds, keypoints) {
    this.viewIds = viewIds;
    this.keypoints = keypoints;
    this.clicks = new Map(viewIds.map((v) => [v, new Map()]));
  }

  get(viewId, keypoint) {
    const view = this.clicks.get(viewId);
    return (view && view.get(keypoint)) || null; // null for a view of another sample too
  }

  // Set (or with null, clear) a click; returns the previous value for undo.
  set(viewId, keypoint, value) {
    const view = this.clicks.get(viewId);
    const previous = view.get(keypoint) || null;
    if (value === null) view.delete(keypoint);
    else view.set(keypoint, { ...value });
    return previous;
  }

  status(viewId, keypoint) {
    const click = this.get(viewId, keypoint);
    return click ? click.visibility : "unset";
  }

  // Whether a keypoint has a position in a view (visible or occluded); a not-annotated one has none.
  placed(viewId, keypoint) {
    const c = this.get(viewId, keypoint);
    return Boolean(c) && c.visibility !== "not_annotated" && c.x !== null;
  }

  // Keypoints placed in a view: what "done" counts (a not-annotated point is not done, only decided).
  doneIn(viewId) {
    return this.keypoints.filter((k) => this.placed(viewId, k)).length;
  }

  notAnnotatedIn(viewId) {
    return this.keypoints.filter((k) => this.status(viewId, k) === "not_annotated").length;
  }

  // The first keypoint after `after` (wrapping) with nothing decided (no point, not marked not annotated);
  // with {placedToo: true}, the first without a position (not-annotated ones included): where a click goes.
  firstUnset(viewId, after = -1, { placedToo = false } = {}) {
    const order = this.keypoints;
    const start = order.indexOf(after) + 1;
    for (let i = 0; i < order.length; i++) {
      const k = order[(start + i) % order.length];
      if (placedToo ? !this.placed(viewId, k) : this.get(viewId, k) === null) return k;
    }
    return null;
  }

  // The submission's clicks: every view and sparse keypoint, unset ones as not annotated.
  toClicks() {
    const out = [];
    for (const viewId of this.viewIds) {
      for (const keypoint of this.keypoints) {
        const c = this.get(viewId, keypoint);
        if (c && c.visibility !== "not_annotated") {
          out.push({ view_id: viewId, keypoint, x: round2(c.x), y: round2(c.y), visibility: c.visibility,
            from_proposal: Boolean(c.from) });
        } else {
          out.push({ view_id: viewId, keypoint, visibility: "not_annotated" });
        }
      }
    }
    return out;
  }
}

function round2(v) {
  return Math.round(v * 100) / 100;
}

export function inside(p, cam) {
  return Boolean(p) && p[0] >= -0.5 && p[1] >= -0.5 && p[0] <= cam.width - 0.5 && p[1] <= cam.height - 0.5;
}

// The keypoint triangulated from the views where it was placed by hand (never from accepted proposals,
// which would only confirm themselves), with its confidence; null with fewer than two such views.
export function triangulateClicked(annotation, cameras, keypoint) {
  const observed = annotation.viewIds
    .map((v) => ({ v, c: annotation.get(v, keypoint) }))
    .filter(({ c }) => c && c.visibility !== "not_annotated" && !c.from);
  if (observed.length < 2) return null;
  const tri = triangulate(observed.map(({ v, c }) => ({ cam: cameras.get(v), pixel: [c.x, c.y] })));
  if (!tri) return null;
  const worst = Math.max(...tri.errors_px);
  return { ...tri, confidence: Math.max(0, 1 - worst / TRIANGULATION_ZERO_CONF_PX) };
}

// Proposals for the keypoints not set in a view, best source first: a point triangulated from the
// annotator's own clicks in the other views, then the API's sources in the server's order (for a detector
// fit: the fit, then the detector; else MVNet, then the current fit). A source with per-keypoint confidences
// (MVNet, the detector) offers only those >= minConf; a fit has no confidence (null).
// Each says whether the fit's mesh hides the keypoint in that view (the fit source's `hidden` flags, whichever
// source the point came from: it is the same hand), so that accepting it marks it occluded.
// cameras: view id -> camera; sources: the API's proposal sources.
// Returns view id -> keypoint -> {x, y, source, confidence (0..1 or null), hidden (bool)}.
export function proposals(annotation, cameras, sources, { minConf = 0.3 } = {}) {
  const out = new Map(annotation.viewIds.map((v) => [v, new Map()]));
  const mesh = sources.find((source) => source.hidden);
  for (const keypoint of annotation.keypoints) {
    const tri = triangulateClicked(annotation, cameras, keypoint);
    for (const viewId of annotation.viewIds) {
      if (annotation.get(viewId, keypoint) !== null) continue;
      const cam = cameras.get(viewId);
      /** @type {import("./annotate_drawing.js").Proposal | null} */
      let proposal = null;
      if (tri) {
        const p = projectPoint(tri.point, cam);
        if (inside(p, cam)) proposal = { x: p[0], y: p[1], source: "triangulated", confidence: tri.confidence };
      }
      for (const source of sources) {
        if (proposal) break;
        const confidence = source.confidences ? source.confidences[keypoint] : null;
        if (confidence !== null && confidence < minConf) continue;
        const p = (source.views[String(viewId)] || [])[keypoint];
        if (inside(p, cam)) proposal = { x: p[0], y: p[1], source: source.kind, confidence };
      }
      if (proposal) {
        proposal.hidden = Boolean(mesh && (mesh.hidden[String(viewId)] || [])[keypoint]);
        out.get(viewId).set(keypoint, proposal);
      }
    }
  }
  return out;
}
