// The FreiHAND export on the admin page: queue an export job (POST /api/admin/exports/freihand; a worker writes
// the layout, as `handloop export --format freihand`, and zips it), follow its progress bar (the job's
// server-sent events), then download the zip (GET .../freihand/{job}/archive). The latest export jobs are
// listed, so an archive made earlier (or by another admin) can be downloaded too.
// Kept out of admin.js: `withFreihandExport` adds this section to the admin page that admin.js mounts.
import { progressBar } from "./admin.js";
import { h, toast, fill } from "./dom.js";
import { paths } from "./api.js";

const FINAL = new Set(["succeeded", "failed", "cancelled"]);

export function withFreihandExport(mount) {
  return async (root, ctx) => {
    const page = await mount(root, ctx);
    const section = h("section", { class: "card", id: "freihand-export" });
    (root.querySelector(".admin-page") || root).append(section);
    const exporter = new FreihandExport(section, ctx.api);
    exporter.start().catch((error) => fill(section, h("h2", {}, "FreiHAND export"), h("p", { class: "error" }, error.message)));
    const unmount = page.unmount ? page.unmount.bind(page) : null;
    page.unmount = () => { exporter.stop(); if (unmount) unmount(); };
    return page;
  };
}

export class FreihandExport {
  constructor(section, api) {
    this.section = section;
    this.api = api;
    this.controller = new AbortController();
    this.live = h("div", { class: "export-live" });
    this.list = h("div", { class: "export-list" });
  }

  stop() {
    this.controller.abort();
  }

  async start() {
    const upTo = h("input", { type: "number", min: 0, name: "up_to_round", placeholder: "up to round (all)", class: "narrow" });
    const project = h("input", { type: "text", name: "project", placeholder: "project (all)" });
    const meshes = h("select", { name: "meshes", "aria-label": "mesh files" },
      ["ply", "obj", "ply,obj", "none"].map((m) => h("option", { value: m }, `meshes: ${m}`)));
    const submit = h("button", { type: "submit", class: "primary" }, "Export in FreiHAND's layout");
    const run = async (e) => {
      e.preventDefault();
      submit.disabled = true;
      try {
        const body = { meshes: meshes.value };
        if (upTo.value !== "") body.up_to_round = Number(upTo.value);
        if (project.value.trim()) body.project = project.value.trim();
        const queued = await this.api.post(paths.freihandExport(), body);
        toast(`export job ${queued.job_id} queued: ${queued.samples} accepted samples`, "ok");
        this.follow(queued.job_id);
      } catch (error) {
        fill(this.live, h("p", { class: "error export-error" }, `export refused: ${error.message}`));
      } finally {
        submit.disabled = false;
      }
    };
    fill(this.section, h("h2", {}, "FreiHAND export"),
      h("p", { class: "muted" }, "The accepted samples in FreiHAND's layout (K, mano, xyz, scale and verts files, " +
        "rgb/ and mask/ images, meshes, a manifest), written by a worker and packed into one zip to download."),
      h("form", { class: "inline-form freihand-form", onsubmit: run }, upTo, project, meshes, submit),
      this.live, this.list);
    await this.renderList();
  }

  // The export jobs so far, newest first, with a download for each that succeeded.
  async renderList() {
    const jobs = await this.api.get(paths.jobs({ kind: "export", limit: 5 }));
    fill(this.list, jobs.length ? h("table", { class: "table" }, h("tbody", {}, jobs.map((j) => h("tr",
      { dataset: { exportJob: String(j.id), state: j.state } }, h("td", {}, `job ${j.id}`), h("td", {}, j.state),
      h("td", { class: "muted" }, j.error || (j.result ? `${j.result.samples.training} training, ` +
        `${j.result.samples.evaluation} evaluation FreiHAND samples (one per view), ` +
        `${(j.result.bytes / 1e6).toFixed(1)} MB` : "")),
      h("td", {}, j.state === "succeeded" ? this.downloadButton(j.id) : ""))))) : null);
  }

  downloadButton(jobId) {
    return h("button", { class: "small download", dataset: { job: String(jobId) }, onclick: () => this.download(jobId) },
      "Download zip");
  }

  async download(jobId) {
    try {
      const blob = await this.api.blob(paths.freihandArchive(jobId));
      const a = h("a", { href: URL.createObjectURL(blob), download: `handloop-freihand-job-${jobId}.zip` });
      document.body.append(a);
      a.click();
      a.remove();
      setTimeout(() => URL.revokeObjectURL(a.href), 60_000);
    } catch (error) {
      toast(`download failed: ${error.message}`, "error", 8000);
    }
  }

  // The job's progress bar from its server-sent events; a download button once it succeeded.
  follow(jobId) {
    const box = h("div", { class: "live", dataset: { job: String(jobId) } });
    fill(this.live, box);
    const draw = (job) => {
      box.dataset.state = job.state;
      box.dataset.progress = String(job.progress);
      fill(box, h("div", { class: "live-head" }, `export job ${job.id}: ${job.state}`,
        h("span", { class: "muted" }, ` ${FINAL.has(job.state) ? "" : job.message || ""}`)),
      progressBar(job.state === "succeeded" ? 1 : job.progress, true),
      job.error ? h("div", { class: "error" }, job.error) : null,
      job.state === "succeeded" ? this.downloadButton(job.id) : null);
    };
    this.api.events(paths.jobEvents(jobId), (name, job) => {
      if (!job) return;
      draw(job);
      if (name === "done") this.renderList().catch(() => null);
    }, this.controller.signal).catch((error) => {
      if (error.name !== "AbortError") box.append(h("div", { class: "error" }, `progress stream: ${error.message}`));
    });
  }
}
