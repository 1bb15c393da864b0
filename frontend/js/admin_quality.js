// Label quality on the admin page (issue 40): blind audits of accepted labels per round and stream (GET
// /api/admin/quality: audited, found wrong, the share and its Wilson 95 % interval, pending), the audit share and
// the precision target as settings (PUT /api/admin/quality/settings), and the heuristic's thresholds in use with
// why they were chosen. Kept out of admin.js: `withQuality` adds this section to the admin page.
import { fmt, h, toast, fill } from "./dom.js";
import { paths } from "./api.js";

export function withQuality(mount) {
  return async (root, ctx) => {
    const page = await mount(root, ctx);
    const section = h("section", { class: "card wide", id: "quality" });
    (root.querySelector(".admin-page") || root).append(section);
    const quality = new QualitySection(section, ctx.api);
    quality.refresh().catch((error) => fill(section, h("h2", {}, "Label quality"),
      h("p", { class: "error" }, `label quality: ${error.message}`)));
    return page;
  };
}

const STREAM_LABEL = { heuristic: "Dʰ heuristic", manual: "Dᵐ verified", annotated: "Dˡ annotated" };
const pct = (x) => (x === null || x === undefined ? "–" : `${fmt(x * 100, 1)} %`);
const interval = (ci) => (ci ? `${fmt(ci[0] * 100, 1)}–${fmt(ci[1] * 100, 1)} %` : "–");

// The share wrong and its interval corrected for the auditors' own error rate (the same without one); the share as
// the auditors called it in the cell's title.
function figureCells(f) {
  return [h("td", { class: "num audited" }, String(f.audited)), h("td", { class: "num wrong" }, String(f.wrong)),
    h("td", { class: "num rate", title: `as called: ${pct(f.error_rate)}` }, pct(f.error_rate_corrected)),
    h("td", { class: "num ci", title: `as called: ${interval(f.error_rate_ci95)}` }, interval(f.error_rate_corrected_ci95)),
    h("td", { class: "num pending" }, String(f.pending))];
}

const mm = (x) => (x === null || x === undefined ? "–" : `${fmt(x, 1)} mm`);
const px = (x) => (x === null || x === undefined ? "–" : `${fmt(x, 1)} px`);

// Agreement (services.review.agreement): two annotators' blind looks at the same samples, per person and overall.
function agreementPart(a) {
  if (!a) return [];
  const row = (who, f, user) => h("tr", { dataset: { user } }, h("td", {}, who),
    h("td", { class: "num pairs" }, String(f.pairs)), h("td", { class: "num px" }, px(f.mean_px)),
    h("td", { class: "num mm" }, mm(f.mean_mm)));
  return [h("h3", {}, "Agreement: samples annotated twice, blind"),
    h("p", { class: "muted" }, `${a.pairs} pairs, ${a.waiting} waiting for a second look, ${a.single ?? 0} ` +
      `annotated once (no other annotator to take a second look), ${a.disputed} disputed ` +
      `(fits over ${fmt(a.dispute_mm, 0)} mm apart: the review decides). ${a.method}.`),
    a.pairs ? h("table", { class: "table quality-agreement" },
      h("thead", {}, h("tr", {}, ["annotator", "pairs", "2D disagreement", "3D disagreement"].map((c) => h("th", {}, c)))),
      h("tbody", {}, row("all", a, "all"), a.people.map((p) => row(`user ${p.user_id}`, p, String(p.user_id))))) : null];
}

// Per person (services.statistics.team_statistics.quality_over_time): each figure this week beside the person's
// earlier weeks and the team median, so a person is compared with themselves and with the team.
const FIGURE_LABEL = { accept_rate: "accept rate", seconds_per_sample: "s per sample", overturned_rate: "overturned",
  gold_agreement: "gold agreement", seconds_per_decision: "s per decision" };
const figureValue = (name, v) => (v === null || v === undefined ? "–"
  : name.startsWith("seconds") ? `${fmt(v, 1)} s` : pct(v));

function peoplePart(p) {
  if (!p || !p.people.length) return [];
  const cell = (name, f) => `${figureValue(name, f.value)}${f.n ? ` (${f.n})` : ""}`;
  const rows = p.people.flatMap((person) => p.figures.filter((f) => person.figures[f.name]).map((f) => {
    const mine = person.figures[f.name];
    return h("tr", { dataset: { user: String(person.user_id), figure: f.name } },
      h("td", {}, person.full_name || person.email), h("td", { title: f.meaning }, FIGURE_LABEL[f.name] || f.name),
      h("td", { class: "num current" }, cell(f.name, mine.current)),
      h("td", { class: "num earlier" }, cell(f.name, mine.earlier)),
      h("td", { class: "num median" }, figureValue(f.name, p.team_median[f.name].current)));
  }));
  return [h("h3", {}, "People over time"),
    h("p", { class: "muted" }, `Week of ${p.current_week} against each person's earlier weeks and the team median ` +
      `(in brackets: the units behind a figure). ${p.method}.`),
    h("table", { class: "table quality-people" },
      h("thead", {}, h("tr", {}, ["person", "figure", "this week", "earlier weeks", "team median (this week)"]
        .map((c) => h("th", {}, c)))),
      h("tbody", {}, rows))];
}

const HEAD = ["audited", "called wrong", "share wrong", "95 % interval (Wilson)", "pending"];

export class QualitySection {
  constructor(section, api) {
    this.section = section;
    this.api = api;
  }

  async refresh() {
    const q = await this.api.get(paths.quality());
    const s = q.settings;
    const share = h("input", { type: "number", min: "0", max: "100", step: "0.5", value: String(s.audit_share * 100),
      class: "audit-share", title: "share of each stream's accepted labels audited blind, percent" });
    const target = h("input", { type: "number", min: "0.1", max: "50", step: "0.1", class: "precision-target",
      value: s.precision_target === null ? "" : String(s.precision_target * 100),
      placeholder: "off", title: "at most this percent of auto-accepted labels wrong; empty: the paper's thresholds" });
    const judge = h("input", { type: "number", min: "0", max: "49", step: "0.5", class: "auditor-error",
      value: String(s.auditor_error_rate * 100), title: "how often an auditor's verdict is itself wrong, percent" });
    const save = async (e) => {
      e.preventDefault();
      try {
        await this.api.put(paths.qualitySettings(), { audit_share: Number(share.value) / 100,
          precision_target: target.value === "" ? null : Number(target.value) / 100,
          auditor_error_rate: Number(judge.value) / 100, gold_share: Number(goldShare.value) / 100,
          agreement_share: Number(twice.value) / 100 });
        toast("quality settings saved", "ok");
        await this.refresh();
      } catch (error) {
        toast(`not saved: ${error.message}`, "error", 8000);
      }
    };
    const goldShare = h("input", { type: "number", min: "0", max: "100", step: "0.5", class: "gold-share",
      value: String(s.gold_share * 100), title: "share of a reviewer's tasks that are gold labels, percent" });
    const twice = h("input", { type: "number", min: "0", max: "100", step: "0.5", class: "agreement-share",
      value: String(s.agreement_share * 100), title: "share of annotated samples a second annotator annotates blind, percent" });
    const goldSample = h("input", { type: "number", min: "1", step: "1", class: "gold-sample", placeholder: "sample id" });
    const markGold = async (e) => {
      e.preventDefault();
      try {
        const g = await this.api.post(paths.qualityGold(), { sample_id: Number(goldSample.value) });
        toast(`sample ${g.sample_id}'s label (${g.stream}) is gold`, "ok");
        goldSample.value = "";
      } catch (error) {
        toast(`not marked: ${error.message}`, "error", 8000);
      }
    };
    const t = q.thresholds;
    fill(this.section, h("h2", {}, "Label quality"),
      h("p", { class: "muted" }, "A random share of every stream's accepted labels goes back to a reviewer blind: the " +
        "task looks like any other (not said to be accepted, nor by whom). A label the audit finds wrong leaves the " +
        "dataset (exports, the round's figures) with the reviewer's reason. Share wrong with its Wilson 95 % interval, " +
        "corrected for the auditors' own error rate (hover: as called)."),
      h("form", { class: "inline-form quality-form", onsubmit: save },
        h("label", {}, "audit share (%) ", share), h("label", {}, " at most wrong of Dʰ (%) ", target),
        h("label", {}, " auditors' error (%) ", judge), h("label", {}, " gold in reviews (%) ", goldShare),
        h("label", {}, " annotated twice (%) ", twice),
        h("button", { type: "submit" }, "Save")),
      h("table", { class: "table quality-streams" },
        h("thead", {}, h("tr", {}, h("th", {}, "stream (all rounds)"), ...HEAD.map((c) => h("th", { class: "num" }, c)))),
        h("tbody", {}, Object.entries(q.streams).map(([stream, f]) => h("tr", { dataset: { stream } },
          h("td", {}, STREAM_LABEL[stream] || stream), ...figureCells(f))))),
      q.rounds.length ? h("table", { class: "table quality-rounds" },
        h("thead", {}, h("tr", {}, h("th", {}, "round"), h("th", {}, "stream"), ...HEAD.map((c) => h("th", { class: "num" }, c)))),
        h("tbody", {}, q.rounds.map((f) => h("tr", { dataset: { round: String(f.round), stream: f.stream } },
          h("td", {}, f.round === null ? "–" : `D${f.round}`), h("td", {}, STREAM_LABEL[f.stream] || f.stream),
          ...figureCells(f))))) : h("p", { class: "muted" }, "No audits yet."),
      h("h3", {}, "Gold labels: each reviewer's agreement"),
      h("form", { class: "inline-form gold-form", onsubmit: markGold }, "Mark an accepted label gold (known right): ",
        goldSample, h("button", { type: "submit" }, "Mark gold")),
      q.gold.length ? h("table", { class: "table quality-gold" },
        h("thead", {}, h("tr", {}, ["reviewer", "gold judged", "agreed", "agreement", "95 % interval"].map((c) => h("th", {}, c)))),
        h("tbody", {}, q.gold.map((g) => h("tr", { dataset: { user: String(g.user_id) } },
          h("td", {}, `user ${g.user_id}`), h("td", { class: "num" }, String(g.gold_judged)),
          h("td", { class: "num" }, String(g.gold_agreed)), h("td", { class: "num" }, pct(g.agreement)),
          h("td", { class: "num" }, interval(g.agreement_ci95)))))) : h("p", { class: "muted" }, "No gold judged yet."),
      ...agreementPart(q.agreement),
      ...peoplePart(q.people),
      t ? h("div", { class: "callout thresholds" }, h("strong", {}, "Heuristic thresholds: "), t.explanation) : null);
    this.section.dataset.ready = "quality";
  }
}
