// The team on the admin page: per-person statistics (GET /api/admin/team/statistics: samples, points placed,
// seconds per sample, the accept rate of their annotations, their decisions and how many were overturned) and
// the accounts that failed logins locked, each with "Unlock" (POST /api/admin/users/{id}/unlock).
// Kept out of admin.js: `withTeam` adds this section to the admin page that admin.js mounts.
import { fmt, h, toast, fill } from "./dom.js";
import { paths } from "./api.js";

export function withTeam(mount) {
  return async (root, ctx) => {
    const page = await mount(root, ctx);
    const section = h("section", { class: "card wide", id: "team" });
    (root.querySelector(".admin-page") || root).append(section);
    const team = new TeamSection(section, ctx.api);
    team.refresh().catch((error) => fill(section, h("h2", {}, "Team"), h("p", { class: "error" }, `team: ${error.message}`)));
    return page;
  };
}

const COLUMNS = [
  ["person", ""], ["role", ""], ["samples", "num"], ["points placed", "num"], ["proposals taken", "num"],
  ["s / sample", "num"], ["accept rate", "num"], ["decisions", "num"], ["s / decision", "num"], ["overturned", "num"],
  ["gold agreement", "num"], // issue 40: gold labels slipped into their reviews (admin_quality.js)
  ["login", ""],
];

export class TeamSection {
  constructor(section, api) {
    this.section = section;
    this.api = api;
  }

  async refresh() {
    const [people, locks] = await Promise.all([this.api.get(paths.teamStatistics()),
      this.api.get(paths.userLocks())]);
    const locked = new Map(locks.map((l) => [l.user_id, l]));
    const rate = (p) => p.accept_rate === null ? "–" : `${Math.round(p.accept_rate * 100)} % of ${p.decided}`;
    const rows = people.map((p) => {
      const lock = locked.get(p.user_id);
      return h("tr", { dataset: { person: p.email } },
        h("td", {}, p.full_name ? `${p.full_name} (${p.email})` : p.email), h("td", {}, p.role),
        h("td", { class: "num samples" }, String(p.samples)), h("td", { class: "num placed" }, String(p.points_placed)),
        h("td", { class: "num taken" }, String(p.proposals_accepted)),
        h("td", { class: "num per-sample" }, fmt(p.seconds_per_sample, 1)), h("td", { class: "num accept-rate" }, rate(p)),
        h("td", { class: "num decisions" }, String(p.decisions)),
        h("td", { class: "num per-decision" }, fmt(p.seconds_per_decision, 1)),
        h("td", { class: "num overturned" }, String(p.overturned)),
        h("td", { class: "num gold" }, p.gold_judged ? `${Math.round(p.gold_agreement * 100)} % of ${p.gold_judged}` : "–"),
        h("td", { class: "lock" }, lock ? [h("span", { class: "badge warn" }, `locked ${lock.retry_after_s} s`), " ",
          h("button", { class: "small unlock", onclick: () => this.unlock(p) }, "Unlock")] : "ok"));
    });
    fill(this.section, h("h2", {}, "Team"),
      h("p", { class: "muted" }, "Per person: the samples they submitted and the points they placed by hand (points " +
        "taken from proposals apart, not-annotated points in neither), active seconds per sample, the share of their " +
        "decided submissions a reviewer accepted, their review decisions and how many someone else later decided " +
        "differently on the same fit. Login: an account locked by failed logins, with Unlock."),
      h("div", { class: "table-scroll" }, h("table", { class: "table team-table" },
        h("thead", {}, h("tr", {}, COLUMNS.map(([t, c]) => h("th", { class: c }, t)))), h("tbody", {}, rows))),
      h("button", { class: "small", onclick: () => this.refresh().catch((e) => toast(e.message, "error")) }, "Refresh"));
    this.section.dataset.loaded = "1";
  }

  async unlock(person) {
    try {
      const result = await this.api.post(paths.unlockUser(person.user_id));
      toast(result.was_locked ? `${person.email} can sign in again` : `${person.email} was not locked`, "ok");
    } catch (error) {
      toast(`unlock failed: ${error.message}`, "error", 8000);
    }
    await this.refresh();
  }
}
