// The admin dashboard: samples per state, the dataset per round and stream (the paper's D_0 ... D_n
// table), charts (growth per round, MVNet confidence, sparsification, human time per action), rounds
// launched and cancelled with a live progress bar (server-sent events), round 0 pre-annotated by the detector,
// jobs, users and roles, exports, and the reliability of the confidences per round.
import { histogram, lines, pairedBars, reliability, stackedBars } from "./charts.js";
import { fmt, h, toast, fill } from "./dom.js";
import { paths } from "./api.js";

const STATES = ["unlabeled", "needs_annotation", "annotated", "fitting", "fitted", "in_review", "accepted", "rejected"];
const STREAMS = [
  { name: "heuristic", label: "Dʰ heuristic", color: "#2a9d8f" },
  { name: "manual", label: "Dᵐ verified", color: "#457b9d" },
  { name: "annotated", label: "Dˡ annotated", color: "#e76f51" },
];
const ROLES = ["annotator", "reviewer", "admin"];
const ROUND_COLORS = ["#e76f51", "#f4a261", "#e9c46a", "#2a9d8f", "#457b9d", "#6d597a"];
const CONFIDENCES = [
  { name: "detector", title: "Detector keypoint score vs 2D error" },
  { name: "triangulation", title: "Triangulation confidence vs 3D error" },
  { name: "mvnet", title: "MVNet confidence vs 3D error" },
];
const REFRESH_MS = 4000;

export async function mountAdmin(root, ctx) {
  const page = new AdminPage(root, ctx);
  await page.start();
  return page;
}

class AdminPage {
  constructor(root, { api, user }) {
    this.api = api;
    this.user = user;
    this.root = root;
    this.watching = new Map(); // job id -> AbortController of its event stream
    // What the last refresh() read (GET /api/admin/...: rounds/statistics, rounds, dashboard, jobs, preannotation).
    /** @type {any} */ this.stats;
    /** @type {any} */ this.rounds;
    /** @type {any} */ this.dashboard;
    /** @type {any} */ this.jobs;
    /** @type {any} */ this.preannotation;
    this.bars = new Map(); // job id -> its progress bar
    this.sections = {
      overview: h("section", { class: "card", id: "overview" }),
      rounds: h("section", { class: "card", id: "rounds" }),
      charts: h("section", { class: "card wide", id: "charts" }),
      jobs: h("section", { class: "card", id: "jobs" }),
      users: h("section", { class: "card", id: "users" }),
      data: h("section", { class: "card", id: "data" }),
      reliability: h("section", { class: "card wide", id: "reliability" }),
    };
    this.progress = h("div", { class: "round-progress" });
    root.append(h("div", { class: "admin-page" }, ...Object.values(this.sections)));
  }

  async start() {
    await this.refresh(); // and follows the round job running now
    this.timer = setInterval(() => this.refresh().catch(() => null), REFRESH_MS);
    this.renderUsers();
    this.renderData();
    this.renderReliability().catch((error) => fill(this.sections.reliability, h("h2", {}, "Reliability"),
      h("p", { class: "error" }, `reliability: ${error.message}`)));
    document.body.dataset.ready = "admin";
  }

  unmount() {
    clearInterval(this.timer);
    for (const controller of this.watching.values()) controller.abort();
  }

  async refresh() {
    const [stats, rounds, dashboard, jobs, preannotation] = await Promise.all([
      this.api.get(paths.roundStatistics()),
      this.api.get(paths.rounds()),
      this.api.get(paths.dashboard()),
      this.api.get(paths.jobs({ limit: 25 })),
      this.api.get(paths.preannotation()),
    ]);
    Object.assign(this, { stats, rounds, dashboard, jobs, preannotation });
    this.renderOverview();
    this.renderRounds();
    this.renderCharts();
    this.renderJobs();
    this.showActiveJob();
  }

  // The progress panel follows the round's job that is running now (one round at a time), never one that
  // ended (a cancelled job's 0 %) while another runs.
  showActiveJob() {
    const active = (this.jobs || []).find((j) => (j.kind === "round" || j.kind === "preannotate")
      && (j.state === "queued" || j.state === "running"));
    if (!active) return;
    const bar = this.bars.get(active.id);
    if (!bar) this.watch(active.id);
    else if (this.progress.firstChild !== bar) fill(this.progress, bar);
  }

  renderOverview() {
    const s = this.stats, d = this.dashboard;
    const counts = s.samples_by_state;
    const total = Object.values(counts).reduce((a, b) => a + b, 0);
    fill(this.sections.overview, 
      h("h2", {}, "Samples"),
      h("div", { class: "state-cards" }, STATES.map((state) => h("div", { class: `state-card state-${state}`,
        dataset: { state } }, h("div", { class: "n" }, String(counts[state] || 0)), h("div", { class: "label" },
        state.replace("_", " "))))),
      h("div", { class: "muted" }, `${total} samples · ${s.submissions} submissions · ${s.clicks} points placed by hand · ` +
        `${d.fits} fits · queues: ${d.queues.annotate} to annotate (+${d.queues.annotate_leased ?? 0} being annotated), ` +
        `${d.queues.review} to review (+${d.queues.review_leased ?? 0} being reviewed)`),
      d.flags ? h("div", { class: "muted annotation-flags" }, `annotators said: no hand in ${d.flags.no_hand_view} ` +
        `view(s) and ${d.flags.no_hand} sample(s) · ${d.flags.skip} skipped · ${d.flags.fit_failed} fit(s) failed on ` +
        "their work (each such sample goes to another annotator)") : null,
      Object.keys(d.fits_by_hand_model).length ? h("div", { class: "fit-models" }, "Fits made with: ",
        Object.entries(d.fits_by_hand_model).map(([label, n]) => h("span", { class: label.includes("not MANO")
          ? "badge warn" : "badge" }, `${label} (${n})`))) : null,
    );
  }

  renderRounds() {
    const s = this.stats;
    const running = this.rounds.find((r) => r.state === "running");
    const rows = s.rounds.map((r) => {
      const meta = this.rounds.find((x) => x.id === r.round_id) || {};
      return h("tr", { dataset: { round: String(r.index) } },
        h("td", {}, `D${sub(r.index)}`), h("td", { class: "round-state" }, r.state,
          meta.failure ? h("div", { class: "error round-failure" }, meta.failure) : null),
        ...STREAMS.map((st) => h("td", { class: "num" }, String(r.added[st.name]))),
        h("td", { class: "num" }, String(r.added_total)), h("td", { class: "num strong" }, String(r.dataset_size_after)),
        h("td", { class: "muted round-decisions" }, decisionSummary(r.decisions)),
        h("td", { class: "muted" }, [meta.mvnet_version, meta.handsegnet_version].filter(Boolean).join(" / ") || "–"),
        h("td", {}, r.state === "running" ? h("button", { class: "danger small", onclick: () => this.cancelRound(r.round_id) },
          "Cancel") : ""));
    });
    const note = h("input", { type: "text", name: "note", placeholder: "note for the next round (optional)" });
    // Launching below the minimum of accepted labels would only fail in training: the button says why.
    const refusal = this.dashboard.launch ? this.dashboard.launch.refusal : null;
    fill(this.sections.rounds, 
      h("h2", {}, "Rounds: D", h("sub", {}, "i+1"), " = D", h("sub", {}, "i"), " + D", h("sup", {}, "h"), " + D",
        h("sup", {}, "m"), " + D", h("sup", {}, "l")),
      h("table", { class: "table rounds-table" },
        h("thead", {}, h("tr", {}, h("th", {}, "round"), h("th", {}, "state"),
          ...STREAMS.map((st) => h("th", { class: "num" }, st.label)), h("th", { class: "num" }, "added"),
          h("th", { class: "num" }, "|D| after"), h("th", {}, "reviewers decided"), h("th", {}, "models"),
          h("th", {}, ""))),
        h("tbody", {}, rows.length ? rows : h("tr", {}, h("td", { colspan: 10, class: "muted" },
          "no round yet: the first accepted sample opens round 0")))),
      h("form", { class: "inline-form", onsubmit: (e) => { e.preventDefault(); this.launchRound(note.value); } },
        note, h("button", { class: "primary launch-round", type: "submit", disabled: Boolean(refusal),
          title: refusal || "" }, running ? `Complete D${sub(running.index)} and launch the next round` :
          "Launch a round"),
        h("button", { type: "button", onclick: () => this.buildReviewQueue() }, "Build review queue")),
      refusal ? h("div", { class: "muted launch-why" }, `Not yet: ${refusal}`) : null,
      this.preannotationForm(),
      this.progress,
    );
  }

  // Round 0 without clicks: the pretrained detector -> triangulation -> fit on a project's unlabeled samples.
  preannotationForm() {
    const p = this.preannotation;
    if (!p) return null;
    const candidates = p.projects.filter((x) => x.unlabeled > 0 && x.running_job_id === null);
    // The section is redrawn at each refresh: the admin's choice is kept across redraws.
    const chosen = this.preannotateChoice || (this.preannotateChoice = { project: null, rest: "keep" });
    const project = h("select", { name: "project", disabled: !p.available || !candidates.length,
      onchange: (e) => { chosen.project = e.target.value; } },
    candidates.map((x) => h("option", { value: String(x.project_id), selected: String(x.project_id) === chosen.project },
      `${x.name} (${x.unlabeled} unlabeled)`)));
    const rest = h("select", { name: "rest", disabled: !p.available, onchange: (e) => { chosen.rest = e.target.value; } },
      h("option", { value: "keep", selected: chosen.rest === "keep" }, "keep the rest for round 1"),
      h("option", { value: "annotate", selected: chosen.rest === "annotate" }, "the rest to annotators"));
    const busy = p.projects.filter((x) => x.running_job_id !== null)
      .map((x) => `${x.name}: job ${x.running_job_id} running`).join(" · ");
    return h("form", { class: "inline-form preannotate", onsubmit: (e) => { e.preventDefault();
      this.preannotate(Number(project.value), rest.value); } },
    project, rest,
    h("button", { type: "submit", class: "preannotate-button", disabled: !p.available || !candidates.length,
      title: p.available ? "detector -> triangulation -> fit; fits that pass the detector's heuristic are accepted (D^h), "
        + "the reviewers see the others" : p.reason },
    "Pre-annotate with the detector (round 0)"),
    h("span", { class: "muted" }, !p.available ? `detector unavailable: ${p.reason}`
      : busy || (candidates.length ? "" : "no unlabeled samples")));
  }

  async preannotate(projectId, rest) {
    try {
      const launched = await this.api.post(paths.preannotation(), { project_id: projectId, rest });
      toast(`pre-annotating ${launched.samples} samples (job ${launched.job_id})`, "ok");
      this.watch(launched.job_id);
      await this.refresh();
    } catch (error) {
      toast(`pre-annotation refused: ${error.message}`, "error", 10000);
    }
  }

  renderCharts() {
    const s = this.stats, d = this.dashboard;
    const growth = stackedBars(s.rounds.map((r) => ({ label: `D${sub(r.index)}`, values: r.added })),
      STREAMS.map((st) => ({ name: st.name, color: st.color })),
      { line: s.rounds.map((r) => r.dataset_size_after), lineLabel: "|D| after the round" });
    const hist = d.confidence_histogram;
    const conf = hist.n
      ? histogram(hist.edges, [{ values: hist.counts, color: "#6c757d", label: "all" },
        { values: hist.accepted, color: "#2a9d8f", label: "accepted" }], { xLabel: "mean confidence (MVNet; the detector's until MVNet predicts)" })
      : h("p", { class: "muted" }, "no MVNet predictions yet");
    const sp = d.sparsification;
    const spars = sp
      ? lines(sp.fractions, [{ ys: sp.curve_mm, color: "#4cc9f0", label: "by confidence" },
        { ys: sp.oracle_mm, color: "#adb5bd", label: "oracle", dashed: true }],
      { xLabel: "fraction removed (least confident first)", yLabel: "mm" })
      : h("p", { class: "muted" }, "needs accepted fits made from MVNet predictions");
    const ht = d.human_time;
    const time = pairedBars([
      { label: "per keypoint", ours: ht.seconds_per_keypoint, reference: ht.paper_seconds.keypoint },
      { label: "per mask", ours: ht.seconds_per_mask, reference: ht.paper_seconds.mask },
      { label: "per verification", ours: ht.seconds_per_verification, reference: ht.paper_seconds.verification },
    ], { labels: ["handloop", "paper"] });
    fill(this.sections.charts, h("h2", {}, "Charts"), h("div", { class: "charts" },
      h("figure", {}, growth, h("figcaption", {}, "Dataset growth per round and stream")),
      h("figure", {}, conf, h("figcaption", {}, `Sample confidence: MVNet's, the detector's in round 0 (${hist.n} samples)`)),
      h("figure", {}, spars, h("figcaption", {}, sp ? `Sparsification vs accepted fits (n=${sp.n}, AUSE ` +
        `${fmt(sp.ause_mm, 2)} mm)` : "Sparsification curve")),
      h("figure", {}, time, h("figcaption", {}, `Human time per action (${ht.annotations} annotations, ` +
        `${ht.verifications} verifications)`))));
  }

  // Do the confidences mean something? Mean true error per confidence bin, a line per round; read on demand
  // (it reads every detection and prediction), not at each refresh.
  async renderReliability() {
    const r = await this.api.get(paths.reliability(10));
    const refs = r.references;
    const figures = CONFIDENCES.map(({ name, title }) => {
      const series = r.rounds.map((round, i) => {
        const b = round.sources[name];
        const points = b.mean_error.map((m, k) => (m === null ? null : [(b.edges[k] + b.edges[k + 1]) / 2, m, b.counts[k]]))
          .filter(Boolean);
        return { label: `D${sub(round.index)}`, color: ROUND_COLORS[i % ROUND_COLORS.length], points, n: b.n };
      }).filter((s) => s.n > 0);
      const unit = r.units[name];
      return h("figure", { dataset: { source: name } }, series.length ? reliability(series, { yLabel: unit })
        : h("p", { class: "muted" }, "no data yet"), h("figcaption", {}, `${title} (${unit})`));
    });
    fill(this.sections.reliability, h("h2", {}, "Reliability of the confidences"),
      h("p", { class: "muted" }, `Reference: ground truth for ${refs.ground_truth} samples, accepted fits for ` +
        `${refs.accepted_fit}. The error should fall as the confidence rises.`),
      h("div", { class: "charts" }, figures),
      h("button", { class: "small", onclick: () => this.renderReliability() }, "Refresh"));
  }

  renderJobs() {
    const rows = this.jobs.map((j) => h("tr", { dataset: { job: String(j.id), state: j.state } },
      h("td", {}, String(j.id)), h("td", {}, j.kind), h("td", { class: "num sample" }, j.sample_id === null ? "–" : String(j.sample_id)),
      h("td", {}, j.state), h("td", { class: "muted started" }, started(j)),
      h("td", { class: "num took" }, duration(j)),
      h("td", {}, progressBar(j.progress)),
      h("td", { class: "muted msg" }, jobMessage(j)),
      h("td", {}, j.state === "queued" || j.state === "running"
        ? h("button", { class: "small", onclick: () => this.cancelJob(j.id) }, "Cancel") : "")));
    fill(this.sections.jobs, h("h2", {}, "Jobs"), h("table", { class: "table" },
      h("thead", {}, h("tr", {}, ...["id", "kind", "sample", "state", "started", "took", "progress", "message", ""]
        .map((t) => h("th", {}, t)))),
      h("tbody", {}, rows)));
  }

  // --- rounds -------------------------------------------------------------------------------------

  async launchRound(note) {
    try {
      const launched = await this.api.post(paths.rounds(), { note });
      toast(`round ${launched.round.index} launched (job ${launched.job_id})`, "ok");
      this.watch(launched.job_id);
      await this.refresh();
    } catch (error) {
      toast(`launch failed: ${error.message}`, "error", 8000);
    }
  }

  async cancelRound(roundId) {
    if (!confirm("Cancel this round and its jobs?")) return;
    try {
      await this.api.post(paths.roundCancel(roundId));
      toast("round cancelled", "ok");
      await this.refresh();
    } catch (error) {
      toast(`cancel failed: ${error.message}`, "error", 8000);
    }
  }

  async cancelJob(jobId) {
    try {
      await this.api.post(paths.jobCancel(jobId));
      await this.refresh();
    } catch (error) {
      toast(`cancel failed: ${error.message}`, "error");
    }
  }

  async buildReviewQueue() {
    try {
      const built = await this.api.post(paths.reviewQueue());
      toast(`${built.queued.length} sample(s) queued for review`, "ok");
      await this.refresh();
    } catch (error) {
      toast(`review queue: ${error.message}`, "error");
    }
  }

  // Live progress of one job from its server-sent events.
  watch(jobId) {
    if (this.watching.has(jobId)) return;
    const controller = new AbortController();
    this.watching.set(jobId, controller);
    const bar = h("div", { class: "live", dataset: { job: String(jobId) } });
    this.bars.set(jobId, bar);
    fill(this.progress, bar);
    const draw = (job) => fill(bar, 
      h("div", { class: "live-head" }, `${job.kind || "round"} job ${job.id}: ${job.state}`, h("span", { class: "muted" },
        ` ${FINAL.has(job.state) ? "" : job.message || ""}`)), progressBar(job.progress, true), phaseSteps(job),
      job.error ? h("div", { class: "error" }, job.error) : null);
    this.api.events(paths.jobEvents(jobId), (name, job) => {
      if (!job) return;
      draw(job);
      bar.dataset.state = job.state;
      bar.dataset.progress = String(job.progress);
      if (name === "done") this.refresh().catch(() => null);
    }, controller.signal).catch((error) => {
      if (error.name !== "AbortError") bar.append(h("div", { class: "error" }, `progress stream: ${error.message}`));
    }).finally(() => this.watching.delete(jobId));
  }

  // --- users --------------------------------------------------------------------------------------

  async renderUsers() {
    const users = await this.api.get(paths.users());
    const email = h("input", { type: "email", name: "email", placeholder: "email", required: true });
    const name = h("input", { type: "text", name: "full_name", placeholder: "name" });
    const password = h("input", { type: "password", name: "password", placeholder: "password (8+)", minlength: 8, required: true });
    const role = h("select", { name: "role" }, ROLES.map((r) => h("option", { value: r }, r)));
    const create = async (e) => {
      e.preventDefault();
      try {
        await this.api.post(paths.users(), { email: email.value, full_name: name.value, password: password.value,
          role: role.value });
        toast(`created ${email.value}`, "ok");
        this.renderUsers();
      } catch (error) {
        toast(`create failed: ${error.message}`, "error", 8000);
      }
    };
    const update = async (user, change) => {
      try {
        await this.api.patch(paths.user(user.id), change);
        toast(`updated ${user.email}`, "ok", 1500);
      } catch (error) {
        toast(`update failed: ${error.message}`, "error", 8000);
      }
      this.renderUsers();
    };
    fill(this.sections.users, h("h2", {}, "Users and roles"), h("table", { class: "table" },
      h("thead", {}, h("tr", {}, h("th", {}, "email"), h("th", {}, "name"), h("th", {}, "role"), h("th", {}, "active"))),
      h("tbody", {}, users.map((u) => h("tr", { dataset: { user: u.email } }, h("td", {}, u.email), h("td", {}, u.full_name),
        h("td", {}, h("select", { onchange: (e) => update(u, { role: e.target.value }) },
          ROLES.map((r) => h("option", { value: r, selected: r === u.role }, r)))),
        h("td", {}, h("input", { type: "checkbox", checked: u.is_active, onchange: (e) => update(u, { is_active: e.target.checked }) })))))),
    h("form", { class: "inline-form", onsubmit: create }, email, name, password, role,
      h("button", { type: "submit" }, "Add user")));
  }

  // --- exports and imports ------------------------------------------------------------------------

  renderData() {
    const upTo = h("input", { type: "number", min: 0, placeholder: "up to round (all)", class: "narrow" });
    const download = async (path, filename) => {
      try {
        const blob = await this.api.blob(path);
        const a = h("a", { href: URL.createObjectURL(blob), download: filename });
        document.body.append(a);
        a.click();
        a.remove();
      } catch (error) {
        toast(`export failed: ${error.message}`, "error");
      }
    };
    const path = h("input", { type: "text", placeholder: "capture directory on the server", class: "wide-input" });
    const project = h("input", { type: "text", placeholder: "project name (optional)" });
    // Round 0 in the same action: the samples come in unlabeled and the detector's job routes them (reviewers
    // first, the rest to the annotators with its proposals). Checked wherever the detector can run.
    const detector = this.preannotation || { available: false, reason: "status not loaded" };
    const preannotate = h("input", { type: "checkbox", name: "preannotate", checked: detector.available,
      disabled: !detector.available });
    const outcome = h("div", { class: "muted import-outcome" });
    const importCapture = async (e) => {
      e.preventDefault();
      try {
        const r = await this.api.post(paths.imports(), { path: path.value, project: project.value || null,
          preannotate: preannotate.checked });
        const round0 = r.preannotation_job_id
          ? `pre-annotation job ${r.preannotation_job_id} queued for ${r.samples} samples: its progress is under Rounds`
          : r.preannotation ? `pre-annotation ${r.preannotation}` : "";
        toast(`imported ${r.project}: ${r.samples} samples, ${r.views} views${round0 ? ` · ${round0}` : ""}`, "ok");
        fill(outcome, `${r.project}: ${r.samples} samples imported${round0 ? `; ${round0}` : ""}`);
        if (r.preannotation_job_id) this.watch(r.preannotation_job_id);
        this.refresh();
      } catch (error) {
        toast(`import failed: ${error.message}`, "error", 10000);
      }
    };
    fill(this.sections.data, 
      h("h2", {}, "Exports"),
      h("div", { class: "inline-form" }, upTo,
        h("button", { onclick: () => download(paths.datasetExport(upTo.value || null),
          "handloop-dataset.json") }, "Dataset (accepted fits)"),
        h("button", { onclick: () => download(paths.samplesExport(), "handloop-samples.json") }, "Sample index"),
        h("button", { onclick: () => download(paths.predictionsExport(), "handloop-predictions.json") }, "Predictions")),
      h("p", { class: "muted" }, "The FreiHAND layout (images, masks, meshes) is written by `handloop export --format freihand`."),
      h("h2", {}, "Import a capture"),
      h("form", { class: "inline-form import-form", onsubmit: importCapture }, path, project,
        h("label", { class: "preannotate-import", title: detector.available
          ? "detector -> triangulation -> fit on every sample; the fits go to the reviewers first" : detector.reason },
        preannotate, " pre-annotate with the detector (round 0)"),
        h("button", { type: "submit" }, "Import")),
      detector.available ? null : h("div", { class: "muted import-why" }, `detector unavailable: ${detector.reason}`),
      outcome);
  }
}

export function progressBar(progress, large = false) {
  const pct = Math.round((progress || 0) * 100);
  return h("div", { class: `progress${large ? " large" : ""}`, role: "progressbar", "aria-valuenow": pct,
    "aria-valuemin": 0, "aria-valuemax": 100 }, h("div", { class: "bar", style: { width: `${pct}%` } }),
  h("span", {}, `${pct}%`));
}

// A round's people's decisions, e.g. "4 accepted · 11 discarded"; discarded samples wait for the next round's fit.
function decisionSummary(decisions) {
  const d = decisions || {};
  const parts = [["accept", "accepted"], ["discard", "discarded"], ["annotate", "to annotators"], ["reject", "rejected"]]
    .filter(([kind]) => d[kind]).map(([kind, label]) => `${d[kind]} ${label}`);
  return parts.length ? parts.join(" · ") : "–";
}

function sub(i) {
  return String(i).split("").map((d) => "₀₁₂₃₄₅₆₇₈₉"[Number(d)]).join("");
}

const FINAL = new Set(["succeeded", "failed", "cancelled"]);

// From creation to the end (or to now while it runs), e.g. "42 s", "3.5 min".
// When a worker started the job's current attempt; a job no worker has started shows since when it waits.
function started(job) {
  if (job.started_at) return new Date(job.started_at).toLocaleTimeString();
  const created = new Date(job.created_at).toLocaleTimeString();
  return FINAL.has(job.state) ? `never (created ${created})` : `waiting since ${created}`;
}

// From the attempt's start (not the job's creation: the wait in the queue is not the work) to its end.
function duration(job) {
  if (!job.started_at) return "–";
  const end = job.finished_at ? Date.parse(job.finished_at) : Date.now();
  const s = Math.max(0, (end - Date.parse(job.started_at)) / 1000);
  return `${s < 120 ? s.toFixed(1) + " s" : (s / 60).toFixed(1) + " min"}${job.finished_at ? "" : " so far"}`;
}

// A round's phases (workers.tasks.round_progress) as steps: done, running (with what it has done), pending.
function phaseSteps(job) {
  const phases = job.result?.phases;
  if (!phases?.length) return null;
  return h("ol", { class: "phases" }, phases.map((p) => h("li", { class: `phase ${p.state}`, dataset: { state: p.state } },
    p.name, p.state === "running" && p.detail ? h("span", { class: "muted" }, ` ${p.detail}`) : null)));
}

// A finished job shows how it ended, not its last progress message ("predicting 0/16").
function jobMessage(job) {
  if (job.error) return job.error;
  if (!FINAL.has(job.state)) return job.message || "";
  const r = job.result, taken = r?.heuristic;
  if (job.state === "succeeded" && job.kind === "preannotate" && r) {  // what round 0 made of it, at a glance
    return `done: ${r.fitted ?? 0} fitted, ${taken ? `${taken.accepted} accepted by the detector's heuristic, ` : ""}`
      + `${r.to_review ?? 0} to review`;
  }
  return job.state === "succeeded" ? "done" : job.state;
}
