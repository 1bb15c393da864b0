// The annotate page's side panel: the sample, the clock and the draft's state, the keypoints of the view on screen
// with their status and proposals, the tools, the buttons (accept, occluded, not annotated, no hand, undo, submit,
// skip), the sources, the last submission and the keys list (HELP). It reads the page's state; its buttons call
// the page.
import { ACCEPT_CONF, confident, proposalLabel, SOURCE_LETTER } from "./annotate_drawing.js";
import { fill, fmt, h, handSide } from "./dom.js";
import { colorOf, SPARSE, SPARSE_LABELS } from "./keypoints.js";

export const HELP = [
  ["1 … 6", "pick wrist, thumb, index, middle, ring, pinky"],
  ["click", "place the keypoint (then the next one is picked); the magnifier beside the cursor shows where"],
  ["drag", "move a point or a proposal"],
  ["A / Enter", `accept the proposal of this keypoint / all of this view's with confidence >= ${ACCEPT_CONF}; ` +
    "those the fit's mesh hides (\"hidden\") as occluded"],
  ["O", "toggle occluded: the point just placed in this view, else the picked one (ringed white)"],
  ["N", "not annotated in this view: the point just placed, else the picked one"],
  ["Del / Backspace", "clear the picked keypoint in this view"],
  ["Tab / Shift+Tab", "next / previous view (or click a thumbnail)"],
  ["M", "mask mode on / off; B brush, E eraser"],
  ["[ ] / wheel", "brush size (wheel in mask mode; Ctrl+wheel zooms)"],
  ["P", "back to points"],
  ["wheel, right-drag", "zoom, pan (Space+drag pans too)"],
  ["+ / - / 0", "zoom in / out at the centre / fit the hand (again: the whole image); each view keeps its zoom"],
  ["H", "hide / show the mask"],
  ["Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y", "undo / redo / redo"],
  ["X", "no hand in this view: every point here not annotated (again: undo the mark)"],
  ["Ctrl+Enter", "submit and show the next task (asks first when points are not set; again: submit as is)"],
  ["Esc", "cancel a drag, give the keys back to the view (from any button)"],
  ["?", "open / close this list"],
];

export function draftLabel(state) {
  return { unsaved: "draft: unsaved changes", saving: "draft: saving…", saved: "draft: saved",
    error: "draft: not saved yet (retrying)", conflict: "draft: changed in another tab too (keep one above)",
    lost: "draft: saved up to the last save; later changes cannot be saved (sample no longer yours)",
  }[state] || "draft: nothing to save";
}

export class AnnotatePanel {
  /** @param {import("./annotate.js").AnnotatePage} page */
  constructor(page) {
    this.page = page;
  }

  renderClock() {
    const page = this.page;
    const el = page.side.querySelector(".clock");
    if (!el || !page.task) return;
    const expires = page.leases.expiresAt(page.task.sample_id);
    const left = expires ? Math.max(0, Math.round((expires - Date.now()) / 1000)) : null;
    if (expires && expires <= Date.now() && !page.lostLease) page.leases.retake(page.task.sample_id).catch(() => null);
    const idle = page.timer.idle() ? ` (paused: no input for ${page.timer.idleCapMs / 1000} s)` : "";
    el.textContent = `time ${fmt(page.timer.spentSeconds(), 0, " s")}${idle} · lease ${left === null ? "–" : `${left} s`}`;
  }

  render() {
    const page = this.page;
    if (!page.task || !page.proposals) return;
    page.publish();
    const view = page.view;
    const props = page.proposals.get(view.id);
    const rows = SPARSE.map((k, i) => {
      const status = page.annotation.status(view.id, k);
      const p = props.get(k);
      const alt = page.alternates.get(view.id).get(k);
      const text = status === "unset" ? (p ? `proposal ${proposalLabel(p)}${p.hidden ? " · hidden" : ""}` +
        `${confident(p) ? "" : " · look"}` +
        (alt ? ` · ${proposalLabel(alt)} ${fmt(Math.hypot(alt.x - p.x, alt.y - p.y), 0, " px")} away` : "") : "–")
        : status.replace("_", " ") + (page.annotation.get(view.id, k).from ? " (accepted)" : "");
      return h("li", { class: `kp-row${k === page.keypoint ? " current" : ""} status-${status}`,
        onclick: () => page.pick(k) },
      h("kbd", {}, String(i + 1)), h("span", { class: "swatch", style: { background: colorOf(k) } }),
      h("span", { class: "kp-name" }, SPARSE_LABELS[i]), h("span", { class: "kp-status" }, text));
    });
    const hiddenCount = [...props.values()].filter((p) => confident(p) && p.hidden).length;
    const total = page.views.reduce((n, v) => n + page.annotation.doneIn(v.id), 0);
    const skipped = page.views.reduce((n, v) => n + page.annotation.notAnnotatedIn(v.id), 0);
    const masks = page.views.filter((v) => v.maskEdited).length;
    const t = page.task;
    fill(page.side, 
      h("div", { class: "sample-head" },
        h("h2", {}, `Sample ${t.sample_id}`),
        h("div", { class: "muted" }, `${t.sequence ?? `sequence ${t.sequence_id}`} · frame ${t.frame_index}`),
        handSide(t.side),
        h("div", { class: "clock muted" }, ""),
        h("div", { class: "draft-state muted" }, draftLabel(document.body.dataset.draftState))),
      page.reviewNote ? h("div", { class: "callout" }, h("strong", {}, "Reviewer: "), page.reviewNote) : null,
      page.fitFailure ? h("div", { class: "callout warn fit-failure-here" }, h("strong", {}, "The last fit failed: "),
        page.fitFailure.reason, ". Its points are kept below; place what is missing, or skip the sample.") : null,
      page.failedFits.length ? h("div", { class: "callout warn fit-failures" },
        h("strong", {}, "Fits that failed on your work: "), page.failedFits.map((f) =>
          h("div", {}, `sample ${f.sample_id}: ${f.reason} (it goes to another annotator)`))) : null,
      h("div", { class: "mode-switch", role: "group" },
        h("button", { class: page.mode === "points" ? "on" : "", onclick: () => page.setMode("points") }, "Points (P)"),
        h("button", { class: page.mode === "mask" && page.tool === "brush" ? "on" : "",
          onclick: () => { page.tool = "brush"; page.setMode("mask"); } }, "Brush (B)"),
        h("button", { class: page.mode === "mask" && page.tool === "eraser" ? "on" : "",
          onclick: () => { page.tool = "eraser"; page.setMode("mask"); } }, "Eraser (E)")),
      h("div", { class: "muted" }, `brush radius ${Math.round(page.radius)} px ([ ] or wheel)`),
      h("h3", {}, `View ${page.viewIndex + 1}/${page.views.length} · ${view.camera}`),
      h("ul", { class: "kp-list" }, rows),
      h("div", { class: "button-row" },
        h("button", { class: "accept-all", onclick: () => page.acceptAllInView(), disabled: props.size === 0 },
          `Accept ${[...props.values()].filter(confident).length} of ${props.size} proposals (Enter)` +
          `${hiddenCount ? ` · ${hiddenCount} as occluded` : ""}`),
        h("button", { onclick: () => page.toggleOccluded() }, "Occluded (O)"),
        h("button", { onclick: () => page.markNotAnnotated() }, "Not annotated (N)"),
        h("button", { class: `no-hand-view${page.noHand.has(view.id) ? " on" : ""}`, onclick: () => page.toggleNoHand() },
          page.noHand.has(view.id) ? "No hand here ✓ (X)" : "No hand here (X)")),
      h("div", { class: "button-row" },
        h("button", { onclick: () => page.undo(), disabled: !page.history.canUndo }, "Undo"),
        h("button", { onclick: () => page.redo(), disabled: !page.history.canRedo }, "Redo")),
      h("div", { class: "totals" }, `${total}/${page.views.length * page.annotation.keypoints.length} keypoints placed · ` +
        `${skipped} not annotated · ${masks} mask(s) corrected`),
      h("button", { class: "primary submit", onclick: () => page.submit(), disabled: page.submitting },
        page.submitting ? "Submitting…" : "Submit (Ctrl+Enter)"),
      h("div", { class: "button-row" },
        h("button", { class: "no-hand-sample", onclick: () => page.askPass("no_hand") }, "No hand in this sample…"),
        h("button", { class: "skip-sample", onclick: () => page.askPass("skip") }, "Skip…")),
      h("div", { class: "muted legend" }, "proposals: T triangulated from your clicks, F current fit, M MVNet, " +
        `D detector; the number is its confidence (orange: below ${ACCEPT_CONF}, Enter leaves it)`),
      page.sources.map((source) => h("div", { class: source.label.includes("not MANO") ? "badge warn" : "badge",
        "data-source": source.kind },
        `${SOURCE_LETTER[source.kind]}: ${source.label}`)),
      page.lastSubmission ? h("div", { class: "muted last-submission" },
        `last: sample ${page.lastSubmission.sample_id} → fit job ${page.lastSubmission.fit_job_id ?? "–"}` +
        (page.lastSubmission.failed ? ` failed: ${page.lastSubmission.failed}` : "")) : null,
      h("details", { class: "help" }, h("summary", {}, "Keys (?)"),
        h("table", {}, HELP.map(([k, d]) => h("tr", {}, h("td", {}, h("kbd", {}, k)), h("td", {}, d))))),
    );
    this.renderClock();
  }
}
