// The calibration check on the admin page (issues 18, 36): per camera, how well the annotators' visible clicks
// agree with the project's calibration (epipolar distance to the other views, and the excess over the best pose),
// the verdict (which camera, turned, moved or swapped names) and the rig's scale judged by the hand's size.
// GET /api/admin/projects/{id}/calibration-check; `handloop calibration check CAPTURE` prints the same figures.
// Kept out of admin.js: `withCalibrationCheck` adds this section to the admin page that admin.js mounts.
import { fmt, h, fill } from "./dom.js";
import { paths } from "./api.js";

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
    const overview = await this.api.get(paths.preannotation());  // lists every project with its name
    const projects = overview.projects || [];
    fill(this.select, projects.map((p) => h("option", { value: String(p.project_id) }, p.name)));
    fill(this.section, h("h2", {}, "Calibration check"),
      h("p", { class: "muted" }, "From the annotators' visible clicks: per camera the median distance to the " +
        "epipolar lines of the other views, and how much of it a better pose of the camera would remove, in pixels."),
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
      const report = await this.api.get(paths.calibrationCheck(Number(this.select.value)));
      fill(this.result, renderReport(report));
    } catch (error) {
      fill(this.result, h("p", { class: "error" }, `calibration check: ${error.message}`));
    }
  }
}

export function renderReport(report) {
  const flagged = new Set(report.flagged);
  const agrees = ["consistent", "pair-consistent", "not-judged"].includes(report.verdict);
  const verdict = h("p", agrees ? { "data-verdict": flagged.size ? "flagged" : "ok" }
    : { class: "callout warn", "data-verdict": flagged.size ? "flagged" : report.verdict },
  report.frames ? `${flagged.size ? `flagged: ${report.flagged.join(", ")}. ` : ""}${report.summary || ""}`
    : "nothing to check yet");
  const scale = report.hand_scale;
  const scaleLine = scale ? h("p", { class: scale.scale_wrong ? "callout warn" : "muted",
    "data-scale": scale.verdict }, scale.message) : null;
  const rows = report.cameras.map((c) => h("tr", { "data-camera": c.name, class: flagged.has(c.name) ? "bad" : "" },
    h("td", {}, c.name), h("td", { class: "num" }, fmt(c.epipolar_px)), h("td", { class: "num" }, fmt(c.threshold_px)),
    h("td", { class: "num" }, fmt(c.excess_px)), h("td", { class: "num" }, String(c.points)),
    h("td", {}, flagged.has(c.name) ? "FLAGGED" : c.judged ? "ok" : "not judged")));
  return [
    h("p", { class: "muted" }, `${report.frames} annotated samples (${report.source})`),
    verdict,
    scaleLine,
    report.cameras.length ? h("table", { class: "table" },
      h("thead", {}, h("tr", {}, ["camera", "epipolar px", "limit px", "excess px", "points", "verdict"]
        .map((t, i) => h("th", { class: i >= 1 && i <= 4 ? "num" : "" }, t)))),
      h("tbody", {}, rows)) : null,
    report.cameras.filter((c) => c.flagged && c.reason).map((c) => h("p", { class: "error" }, c.reason)),
    (report.notes || []).map((n) => h("p", { class: "muted" }, `note: ${n}`)),
  ];
}
