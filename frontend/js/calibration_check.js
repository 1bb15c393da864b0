// The calibration check on the admin page (issue 18): per camera, how well the annotators' visible clicks
// agree with the project's calibration (epipolar distance to the other views, reprojection of the triangulated
// points), and a flag on a camera that disagrees with the others (a swapped name, a stale extrinsic).
// GET /api/admin/projects/{id}/calibration-check; `handloop calibration check CAPTURE` prints the same figures.
// Kept out of admin.js: `withCalibrationCheck` adds this section to the admin page that admin.js mounts.
import { fmt, h, fill } from "./dom.js";

export function withCalibrationCheck(mount) {
  return async (root, ctx) => {
    const page = await mount(root, ctx);
    const section = h("section", { class: "card wide", id: "calibration-check" });
    (root.querySelector(".admin-page") || root).append(section);
    const check = new CalibrationCheck(section, ctx.api);
    check.start().catch((error) => check.fail(error));
    return page;
  };
}

export class CalibrationCheck {
  constructor(section, api) {
    this.section = section;
    this.api = api;
    this.select = h("select", { name: "calibration-project", "aria-label": "project" });
    this.result = h("div", { class: "calibration-result" });
  }

  async start() {
    const overview = await this.api.get("/api/admin/preannotation");  // lists every project with its name
    const projects = overview.projects || [];
    fill(this.select, projects.map((p) => h("option", { value: String(p.project_id) }, p.name)));
    fill(this.section, h("h2", {}, "Calibration check"),
      h("p", { class: "muted" }, "From the annotators' visible clicks: per camera the median distance to the " +
        "epipolar lines of the other views and the reprojection error of the triangulated points, in pixels."),
      h("form", { class: "inline-form", onsubmit: (e) => { e.preventDefault(); this.run(); } },
        this.select, h("button", { type: "submit", disabled: !projects.length }, "Check calibration")),
      projects.length ? this.result : h("p", { class: "muted" }, "no project imported yet"));
  }

  fail(error) {
    fill(this.section, h("h2", {}, "Calibration check"), h("p", { class: "error" }, `calibration check: ${error.message}`));
  }

  async run() {
    fill(this.result, h("p", { class: "muted" }, "checking…"));
    try {
      const report = await this.api.get(`/api/admin/projects/${Number(this.select.value)}/calibration-check`);
      fill(this.result, renderReport(report));
    } catch (error) {
      fill(this.result, h("p", { class: "error" }, `calibration check: ${error.message}`));
    }
  }
}

export function renderReport(report) {
  const flagged = new Set(report.flagged);
  const verdict = flagged.size
    ? h("p", { class: "callout warn", "data-verdict": "flagged" }, `flagged: ${report.flagged.join(", ")}`)
    : h("p", { "data-verdict": "ok" }, report.frames ? "no camera disagrees with the others" : "nothing to check yet");
  const rows = report.cameras.map((c) => h("tr", { "data-camera": c.name, class: flagged.has(c.name) ? "bad" : "" },
    h("td", {}, c.name), h("td", { class: "num" }, fmt(c.epipolar_px)), h("td", { class: "num" }, fmt(c.threshold_px)),
    h("td", { class: "num" }, fmt(c.reprojection_px)), h("td", { class: "num" }, String(c.points)),
    h("td", {}, flagged.has(c.name) ? "FLAGGED" : "ok")));
  return [
    h("p", { class: "muted" }, `${report.frames} annotated samples (${report.source})`),
    verdict,
    report.cameras.length ? h("table", { class: "table" },
      h("thead", {}, h("tr", {}, ["camera", "epipolar px", "limit px", "reprojection px", "points", "verdict"]
        .map((t, i) => h("th", { class: i >= 1 && i <= 4 ? "num" : "" }, t)))),
      h("tbody", {}, rows)) : null,
    report.cameras.filter((c) => c.flagged && c.reason).map((c) => h("p", { class: "error" }, c.reason)),
    (report.notes || []).map((n) => h("p", { class: "muted" }, `note: ${n}`)),
  ];
}
