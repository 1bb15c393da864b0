// Drawing helpers shared by the pages; all coordinates are screen (CSS) pixels. Markers carry a dark and a
// light ring, so every keypoint colour (the grey wrist, the blue fingers) stands out on skin, mask and
// background alike.
import { colorOf } from "./keypoints.js";

// look: a proposal to check before accepting (below the confidence Enter accepts): an orange ring.
export function marker(ctx, x, y, keypoint, { style = "solid", r = 6, label = null, selected = false, look = false } = {}) {
  const color = colorOf(keypoint);
  ctx.save();
  ctx.lineWidth = selected ? 3 : 2;
  if (style === "proposal") {
    ctx.strokeStyle = "rgba(0, 0, 0, 0.75)";
    ctx.lineWidth = 4;
    ctx.beginPath();
    ctx.arc(x, y, r + 2, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.lineWidth = selected ? 3 : 2;
    ctx.setLineDash([3, 3]);
    ctx.strokeStyle = color;
    ctx.beginPath();
    ctx.arc(x, y, r + 2, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.setLineDash([]);
    ctx.fillStyle = color;
    ctx.fillRect(x - 1, y - 1, 2, 2);
    if (look) {
      ctx.strokeStyle = "#ff9f1c";
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.arc(x, y, r + 6, 0, 2 * Math.PI);
      ctx.stroke();
    }
  } else if (style === "alternate") {
    // A second source's point for the same keypoint (the detector's beside the fit's): a thin dotted ring.
    ctx.strokeStyle = "rgba(0, 0, 0, 0.75)";
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.arc(x, y, r, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.lineWidth = 1.5;
    ctx.setLineDash([1, 3]);
    ctx.strokeStyle = color;
    ctx.beginPath();
    ctx.arc(x, y, r, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.setLineDash([]);
  } else if (style === "occluded") {
    ctx.strokeStyle = "#fff";
    ctx.fillStyle = color;
    ctx.beginPath();
    ctx.rect(x - r, y - r, 2 * r, 2 * r);
    ctx.fill();
    ctx.stroke();
  } else if (style === "fit") {
    ctx.strokeStyle = color;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(x - r, y);
    ctx.lineTo(x + r, y);
    ctx.moveTo(x, y - r);
    ctx.lineTo(x, y + r);
    ctx.stroke();
  } else {
    ctx.fillStyle = color;
    ctx.strokeStyle = r <= 3 ? "rgba(0, 0, 0, 0.85)" : "#fff";
    if (r <= 3) ctx.lineWidth = 1;
    ctx.beginPath();
    ctx.arc(x, y, r, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
    if (r > 3) {
      ctx.strokeStyle = "rgba(0, 0, 0, 0.85)"; // the contrasting outer ring
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.arc(x, y, r + 1.75, 0, 2 * Math.PI);
      ctx.stroke();
    }
  }
  if (selected) {
    ctx.strokeStyle = "#ffd60a";
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(x, y, r + 5, 0, 2 * Math.PI);
    ctx.stroke();
  }
  if (label) {
    ctx.font = "11px system-ui, sans-serif";
    ctx.fillStyle = "#fff";
    ctx.strokeStyle = "rgba(0,0,0,0.8)";
    ctx.lineWidth = 3;
    ctx.strokeText(label, x + r + 3, y - r - 1);
    ctx.fillText(label, x + r + 3, y - r - 1);
  }
  ctx.restore();
}

export function segment(ctx, a, b, color, width = 2, dash = null) {
  ctx.save();
  ctx.strokeStyle = color;
  ctx.lineWidth = width;
  if (dash) ctx.setLineDash(dash);
  ctx.beginPath();
  ctx.moveTo(a[0], a[1]);
  ctx.lineTo(b[0], b[1]);
  ctx.stroke();
  ctx.restore();
}
