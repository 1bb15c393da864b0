// Small SVG charts for the dashboard (bars, histogram, lines, reliability). A charting library would need a
// build step or a CDN; these five shapes are all the dashboard draws.
const NS = "http://www.w3.org/2000/svg";

function el(tag, attrs = {}, text = null) {
  const node = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, String(v));
  if (text !== null) node.textContent = text;
  return node;
}

// A shape with a hover title, appended to `parent`.
function add(parent, tag, attrs, title) {
  const node = el(tag, attrs);
  if (title) node.append(el("title", {}, title));
  parent.append(node);
  return node;
}

function frame(width, height, margin) {
  const svg = el("svg", { viewBox: `0 0 ${width} ${height}`, class: "chart", role: "img" });
  const plot = { x0: margin.left, y0: height - margin.bottom, x1: width - margin.right, y1: margin.top };
  return { svg, plot };
}

function niceMax(v) {
  if (!(v > 0)) return 1;
  const p = 10 ** Math.floor(Math.log10(v));
  for (const m of [1, 2, 2.5, 5, 10]) if (m * p >= v) return m * p;
  return 10 * p;
}

function yAxis(svg, plot, max, ticks = 4, fmt = (v) => String(Math.round(v * 100) / 100)) {
  for (let i = 0; i <= ticks; i++) {
    const v = (max * i) / ticks;
    const y = plot.y0 - ((plot.y0 - plot.y1) * i) / ticks;
    svg.append(el("line", { x1: plot.x0, x2: plot.x1, y1: y, y2: y, class: "grid" }));
    svg.append(el("text", { x: plot.x0 - 4, y: y + 3, class: "tick", "text-anchor": "end" }, fmt(v)));
  }
}

// One row of legend entries above the plot area.
function legend(svg, items, x, y) {
  let cx = x;
  for (const [label, color, dashed] of items) {
    svg.append(el("line", { x1: cx, x2: cx + 12, y1: y, y2: y, stroke: color, "stroke-width": 3,
      "stroke-dasharray": dashed ? "4 3" : "none" }));
    svg.append(el("text", { x: cx + 15, y: y + 3, class: "tick" }, label));
    cx += 24 + 5.2 * label.length;
  }
}

// Stacked bars per category (parts: [{name, color}]), optionally a line on the same axis (e.g. |D|).
export function stackedBars(categories, parts, { line = null, lineLabel = "", width = 420, height = 220 } = {}) {
  const { svg, plot } = frame(width, height, { left: 40, right: 10, top: 26, bottom: 26 });
  const totals = categories.map((c) => parts.reduce((s, p) => s + (c.values[p.name] || 0), 0));
  const max = niceMax(Math.max(1, ...totals, ...(line || [0])));
  yAxis(svg, plot, max);
  const n = Math.max(1, categories.length);
  const slot = (plot.x1 - plot.x0) / n;
  const bw = Math.min(40, slot * 0.6);
  const y = (v) => plot.y0 - ((plot.y0 - plot.y1) * v) / max;
  categories.forEach((c, i) => {
    let acc = 0;
    const x = plot.x0 + slot * (i + 0.5) - bw / 2;
    for (const p of parts) {
      const v = c.values[p.name] || 0;
      if (v > 0) add(svg, "rect", { x, y: y(acc + v), width: bw, height: y(acc) - y(acc + v), fill: p.color },
        `${c.label} ${p.name}: ${v}`);
      acc += v;
    }
    svg.append(el("text", { x: x + bw / 2, y: plot.y0 + 14, class: "tick", "text-anchor": "middle" }, c.label));
  });
  if (line && line.length) {
    const pts = line.map((v, i) => `${plot.x0 + slot * (i + 0.5)},${y(v)}`).join(" ");
    svg.append(el("polyline", { points: pts, fill: "none", stroke: "#ffd60a", "stroke-width": 2 }));
    line.forEach((v, i) => svg.append(el("circle", { cx: plot.x0 + slot * (i + 0.5), cy: y(v), r: 3, fill: "#ffd60a" })));
  }
  legend(svg, [...parts.map((p) => [p.name, p.color]), ...(line ? [[lineLabel, "#ffd60a"]] : [])], plot.x0, 9);
  return svg;
}

// Histogram over bin edges with overlaid series [{values, color, label}].
export function histogram(edges, series, { width = 420, height = 200, xLabel = "" } = {}) {
  const { svg, plot } = frame(width, height, { left: 40, right: 10, top: 26, bottom: 30 });
  const max = niceMax(Math.max(1, ...series.flatMap((s) => s.values)));
  yAxis(svg, plot, max);
  const n = edges.length - 1;
  const bw = (plot.x1 - plot.x0) / n;
  const y = (v) => plot.y0 - ((plot.y0 - plot.y1) * v) / max;
  series.forEach((s, j) => {
    s.values.forEach((v, i) => {
      if (!v) return;
      const inset = j * bw * 0.2;
      add(svg, "rect", { x: plot.x0 + i * bw + inset, y: y(v), width: Math.max(1, bw - 1 - 2 * inset),
        height: plot.y0 - y(v), fill: s.color }, `${edges[i]}–${edges[i + 1]}: ${v}`);
    });
  });
  for (let i = 0; i <= n; i += Math.max(1, Math.round(n / 5))) {
    svg.append(el("text", { x: plot.x0 + i * bw, y: plot.y0 + 13, class: "tick", "text-anchor": "middle" }, edges[i]));
  }
  svg.append(el("text", { x: (plot.x0 + plot.x1) / 2, y: height - 2, class: "tick", "text-anchor": "middle" }, xLabel));
  legend(svg, series.map((s) => [s.label, s.color]), plot.x0, 9);
  return svg;
}

// Lines over shared xs: series [{ys, color, label, dashed}].
export function lines(xs, series, { width = 420, height = 200, xLabel = "", yLabel = "" } = {}) {
  const { svg, plot } = frame(width, height, { left: 44, right: 10, top: 26, bottom: 30 });
  const max = niceMax(Math.max(1e-9, ...series.flatMap((s) => s.ys.filter(Number.isFinite))));
  yAxis(svg, plot, max);
  const x0 = Math.min(...xs), x1 = Math.max(...xs);
  const x = (v) => plot.x0 + ((plot.x1 - plot.x0) * (v - x0)) / (x1 - x0 || 1);
  const y = (v) => plot.y0 - ((plot.y0 - plot.y1) * v) / max;
  for (const s of series) {
    const pts = xs.map((xv, i) => `${x(xv)},${y(s.ys[i])}`).join(" ");
    svg.append(el("polyline", { points: pts, fill: "none", stroke: s.color, "stroke-width": 2,
      "stroke-dasharray": s.dashed ? "5 4" : "none" }));
  }
  for (const v of [x0, (x0 + x1) / 2, x1]) {
    svg.append(el("text", { x: x(v), y: plot.y0 + 13, class: "tick", "text-anchor": "middle" }, Math.round(v * 100) / 100));
  }
  svg.append(el("text", { x: (plot.x0 + plot.x1) / 2, y: height - 2, class: "tick", "text-anchor": "middle" }, xLabel));
  svg.append(el("text", { x: 10, y: plot.y1 - 2, class: "tick" }, yLabel));
  legend(svg, series.map((s) => [s.label, s.color, s.dashed]), plot.x0, 9);
  return svg;
}

// Reliability: mean true error per confidence bin, one line per series ({label, color, points: [[x, y, n]]}),
// x the bin centre in [0, 1]; empty bins are simply absent (a line joins the bins that have data).
export function reliability(series, { width = 420, height = 200, yLabel = "" } = {}) {
  const { svg, plot } = frame(width, height, { left: 44, right: 10, top: 26, bottom: 30 });
  const max = niceMax(Math.max(1e-9, ...series.flatMap((s) => s.points.map((p) => p[1]))));
  yAxis(svg, plot, max);
  const x = (v) => plot.x0 + (plot.x1 - plot.x0) * v;
  const y = (v) => plot.y0 - ((plot.y0 - plot.y1) * v) / max;
  for (const s of series) {
    if (s.points.length > 1) {
      svg.append(el("polyline", { points: s.points.map(([px, py]) => `${x(px)},${y(py)}`).join(" "), fill: "none",
        stroke: s.color, "stroke-width": 2 }));
    }
    for (const [px, py, n] of s.points) {
      add(svg, "circle", { cx: x(px), cy: y(py), r: 3, fill: s.color }, `${s.label}: confidence ${px.toFixed(2)}, ` +
        `mean error ${py} ${yLabel} (n=${n})`);
    }
  }
  for (const v of [0, 0.5, 1]) svg.append(el("text", { x: x(v), y: plot.y0 + 13, class: "tick", "text-anchor": "middle" }, v));
  svg.append(el("text", { x: (plot.x0 + plot.x1) / 2, y: height - 2, class: "tick", "text-anchor": "middle" }, "confidence"));
  svg.append(el("text", { x: 10, y: plot.y1 - 2, class: "tick" }, yLabel));
  legend(svg, series.map((s) => [s.label, s.color]), plot.x0, 9);
  return svg;
}

// Pairs of bars (ours vs a reference) per category.
export function pairedBars(categories, { width = 420, height = 200, labels = ["ours", "paper"], unit = "s" } = {}) {
  const { svg, plot } = frame(width, height, { left: 40, right: 10, top: 26, bottom: 26 });
  const max = niceMax(Math.max(1, ...categories.flatMap((c) => [c.ours ?? 0, c.reference ?? 0])));
  yAxis(svg, plot, max);
  const slot = (plot.x1 - plot.x0) / Math.max(1, categories.length);
  const bw = Math.min(28, slot * 0.3);
  const y = (v) => plot.y0 - ((plot.y0 - plot.y1) * v) / max;
  const colors = ["#4cc9f0", "#6c757d"];
  categories.forEach((c, i) => {
    const cx = plot.x0 + slot * (i + 0.5);
    [c.ours, c.reference].forEach((v, j) => {
      if (v === null || v === undefined) return;
      const x = cx - bw + j * bw;
      add(svg, "rect", { x, y: y(v), width: bw - 2, height: plot.y0 - y(v), fill: colors[j] }, `${labels[j]}: ${v} ${unit}`);
      svg.append(el("text", { x: x + bw / 2 - 1, y: y(v) - 3, class: "tick", "text-anchor": "middle" }, Number(v).toFixed(1)));
    });
    svg.append(el("text", { x: cx, y: plot.y0 + 14, class: "tick", "text-anchor": "middle" }, c.label));
  });
  legend(svg, labels.map((l, j) => [l, colors[j]]), plot.x0, 9);
  return svg;
}
