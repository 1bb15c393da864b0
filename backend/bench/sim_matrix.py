"""`handloop bench sim-matrix`: the loop judged over seeds no one tuned on, two view widths, two kinds of
simulated people and annotators who take proposals or not (issue 37); docs/evaluation.md, "The matrix".

Each run is `handloop bench sim`'s step-counted simulation (`backend.bench.sim`: the FULL plan, MVNet and
HandSegNet trained a fixed number of steps a round) on a capture synthesised with the run's seed, with the
people's random streams seeded by it too. Runs go one after the other; each finished run is written to the results
file at once, so an interrupted matrix keeps what it finished and `--resume` runs only the rest.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import os
import shutil
import statistics
import sys
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from dotenv import dotenv_values
from tqdm import tqdm

from backend.bench import sim
from backend.bench.common import emit, git_commit
from backend.services.review.verification import REVIEW_RANKS
from backend.services.rounds import preannotation
from backend.settings import Settings, get_settings
from backend.simulation.annotator import AnnotatorConfig
from backend.simulation.reviewer import ReviewerConfig

log = logging.getLogger(__name__)

# The matrix's own seeds: no test, tuning run or docs example may use them, so the matrix measures the loop on
# captures and people no one tuned it to. Replace them (and say so in docs/benchmarks.md) if one is ever tuned on.
UNSEEN_SEEDS = (3307, 4519, 7741)
WIDTHS_PX = (320, 640)
# The people: the simulation's defaults (AnnotatorConfig: 2 px click noise, 5 % swapped fingertips per view) and
# noisier ones.
PEOPLE: dict[str, dict[str, float]] = {"default": {}, "noisy": {"click_sigma_px": 3.0, "swap_probability": 0.08}}
# Annotators accept the proposal the page shows within this many pixels of the true point (one key per view), or
# click every point.
PROPOSALS = {"proposals": 4.0, "no-proposals": None}
# The issue's step counts: MVNet (every network's cap) and HandSegNet's own, a round.
TRAIN_STEPS, HANDSEGNET_STEPS = 650, 1650
ROUNDS = 4
# The simulated reviewers discard a bad fit from predictions once (it waits for the next round's fit) before they send
# it to the annotators, as the paper's reviewers discarded most fits they did not accept (`--reviewer-discards`;
# ReviewerConfig.discards_before_annotation; until 2026-12-07 every bad fit went to the annotators: 0).
REVIEWER_DISCARDS = 1
# In round 0 they discard a bad detector fit the same way once D_0 holds this many labels (`--reviewer-round0-floor`;
# ReviewerConfig.round0_discard_floor); None: round 0's bad fits all go to the annotators.
REVIEWER_ROUND0_FLOOR: int | None = None
MAX_REVIEW_CAPACITY = 1_000_000  # as the setting's own bound
# Settings that do not change what a run measures (places, accounts, the service's plumbing). Any other HANDLOOP_*
# setting in the environment reaches the runs' stacks, so it is recorded with the results and must match on
# --resume (`loop_environment`); names with these words are never recorded (secrets, addresses).
PLUMBING_SETTINGS = frozenset({
    "data_dir", "environment", "db_pool_size", "db_max_overflow", "access_token_minutes", "auth_cache_seconds",
    "import_roots", "trusted_proxies", "max_upload_bytes", "image_cache_seconds", "sse_poll_seconds",
    "broker_prefix", "broker_visibility_timeout_s", "broker_check_cache_s", "fit_dispatch_linger_s", "outbox_poll_s",
    "job_redispatch_after_s", "job_heartbeat_timeout_s", "job_max_attempts", "task_time_limit_s",
    "fit_task_time_limit_s", "worker_concurrency"})
NEVER_RECORDED = ("secret", "password", "token", "url", "login_")
ENV_PREFIX = str(Settings.model_config.get("env_prefix") or "").upper()


@dataclass(frozen=True)
class Cell:
    """One configuration of the matrix, run once per seed."""

    width_px: int
    people: str  # a key of PEOPLE
    proposals: str  # a key of PROPOSALS

    @property
    def name(self) -> str:
        return f"{self.width_px}-{self.people}-{self.proposals}"

    def annotator(self, seed: int) -> AnnotatorConfig:
        return AnnotatorConfig(**PEOPLE[self.people], accept_proposals_within_px=PROPOSALS[self.proposals], seed=seed)


CELLS = {c.name: c for c in (Cell(w, p, a) for w in WIDTHS_PX for p in PEOPLE for a in PROPOSALS)}
# The issue's targets, on the median over the seeds: per cell, (value key, its round, at least / at most, threshold).
# A value not measured (a run stopped before the round, or fewer rounds) does not meet its target.
HEADLINE_TARGETS = {
    "640-default-proposals": (("labels_per_human_hour", 2, "min", 600.0),
                              ("heuristic_share_by_round_2", 2, "min", 0.40)),
    "320-noisy-no-proposals": (("labels_per_human_hour", 4, "min", 200.0),),
}
HEADLINE = tuple(HEADLINE_TARGETS)
ACCEPTED_VERTEX_MM_MAX = 6.0  # every cell: accepted labels' mean vertex error
RESULTS_VERSION = 1


def parse_cells(text: str) -> list[Cell]:
    """"all", "headline", or cell names separated by commas -> the cells, in the order given (each once)."""
    names = {"all": list(CELLS), "headline": list(HEADLINE)}.get(text.strip())
    if names is None:
        names = [n.strip() for n in text.split(",") if n.strip()]
        unknown = [n for n in names if n not in CELLS]
        if unknown or not names:
            raise ValueError(f"unknown cells {unknown or [text]}: pick from all, headline, {', '.join(CELLS)}")
    return [CELLS[n] for n in dict.fromkeys(names)]


def parse_seeds(text: str | None) -> tuple[int, ...]:
    """None -> the unseen seeds; else integers separated by commas, no repeats."""
    if text is None:
        return UNSEEN_SEEDS
    try:
        seeds = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError as exc:
        raise ValueError(f"seeds must be integers separated by commas, not {text!r}") from exc
    if not seeds or len(set(seeds)) != len(seeds) or any(s < 0 for s in seeds):
        raise ValueError(f"seeds must be distinct non-negative integers, at least one, not {text!r}")
    return seeds


# --- what a run is measured by ---------------------------------------------------------------------------------
def labels_per_hour_by_round(rounds: list[dict[str, Any]]) -> list[float | None]:
    """Per round, the labels added so far over the human hours so far (the run's `labels_per_human_hour` at its
    last round); None while no human time was spent."""
    out: list[float | None] = []
    labels = hours = 0.0
    for r in rounds:
        labels += r["added_total"]
        hours += r["human_hours"]
        out.append(labels / hours if hours > 0 else None)
    return out


def _mvnet_mm(rounds: list[dict[str, Any]]) -> float | None:
    """MVNet's mean keypoint error (mm) in the last round that predicted."""
    measured = [r["mvnet_keypoint_mm"] for r in rounds if r.get("mvnet_keypoint_mm") is not None]
    return measured[-1] if measured else None


def run_record(cell: Cell, seed: int, summary: dict[str, Any], work: Path) -> dict[str, Any]:
    """What the matrix keeps of one simulation (the whole summary stays in `<work>/simulation.json`)."""
    rounds = summary["rounds"]
    return {"cell": cell.name, "seed": seed, "rounds_completed": summary["rounds_completed"],
            "stopped": summary.get("stopped"), "dataset_size": summary["dataset_size"],
            "human_hours": summary["human_hours"], "labels_per_human_hour": summary["labels_per_human_hour"],
            "labels_per_human_hour_by_round": labels_per_hour_by_round(rounds),
            "heuristic_share_by_round_2": sim.detector_values(summary)["heuristic_share_by_round_2"]
            if any(r["index"] >= 2 for r in rounds) else None,
            "auto_accept_precision": summary["auto_accept_precision"],
            "additions": [r["added_total"] for r in rounds], "added": [r["added"] for r in rounds],
            "mvnet_keypoint_mm": _mvnet_mm(rounds), "accepted_vertex_mm": summary["accepted_vertex_mm"],
            "rank_spearman_by_round": [rank_spearman(r) for r in rounds],
            "bookkeeping_ok": summary["bookkeeping_ok"], "minutes": summary["minutes"], "work_dir": str(work)}


def rank_spearman(report: dict[str, Any]) -> dict[str, float | None] | None:
    """A round's review ranks -> how well each ordered its candidate fits by true error (Spearman, +1 best-first;
    backend.simulation.ranking); None where the round had none (round 0, or a run recorded before the figure)."""
    quality = report.get("rank_quality")
    return None if quality is None else {rank: f["spearman"] for rank, f in quality["by_rank"].items()}


def _median(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return float(statistics.median(known)) if known else None


def _worst(values: list[float | None], higher_is_better: bool) -> float | None:
    known = [v for v in values if v is not None]
    return (min(known) if higher_is_better else max(known)) if known else None


def _at_round(run: dict[str, Any], index: int) -> float | None:
    by_round = run["labels_per_human_hour_by_round"]
    return by_round[index] if index < len(by_round) else None


def additions_grow(additions: list[float | None]) -> bool | None:
    """From round 1 on, each round adds at least as many labels as the round before (the issue's "from round 1 to
    round 2, and to round 4"; round 0's additions are the detector's bulk, which the paper's rounds also fell from:
    691 then 456). `additions` by round, round 0 first; None before round 2."""
    later = additions[1:]
    if len(later) < 2 or any(a is None for a in later):
        return None
    return all(b >= a for a, b in itertools.pairwise(later))


def cell_summary(cell: Cell, runs: list[dict[str, Any]]) -> dict[str, Any]:
    """A cell over its seeds: medians and the worst seed's figure (lowest rate, share and precision, highest
    error), additions per round as the median over the seeds, and the issue's targets where the cell has some."""
    rates = [r["labels_per_human_hour"] for r in runs]
    rates_2 = [_at_round(r, 2) for r in runs]
    shares = [r["heuristic_share_by_round_2"] for r in runs]
    precision = [r["auto_accept_precision"] for r in runs]
    mvnet = [r["mvnet_keypoint_mm"] for r in runs]
    accepted = [r["accepted_vertex_mm"] for r in runs]
    longest = max((len(r["additions"]) for r in runs), default=0)
    additions = [_median([r["additions"][i] if i < len(r["additions"]) else None for r in runs])
                 for i in range(longest)]
    out = {"cell": cell.name, "width_px": cell.width_px, "people": cell.people, "proposals": cell.proposals,
           "seeds": [r["seed"] for r in runs], "runs": len(runs),
           "stopped": sum(1 for r in runs if r["stopped"]),
           "labels_per_human_hour": {"median": _median(rates), "worst": _worst(rates, True)},
           "labels_per_human_hour_by_round_2": {"median": _median(rates_2), "worst": _worst(rates_2, True)},
           "heuristic_share_by_round_2": {"median": _median(shares), "worst": _worst(shares, True)},
           "auto_accept_precision": {"median": _median(precision), "worst": _worst(precision, True)},
           "additions_per_round": additions, "additions_grow": additions_grow(additions),
           "mvnet_keypoint_mm": {"median": _median(mvnet), "worst": _worst(mvnet, False)},
           "accepted_vertex_mm": {"median": _median(accepted), "worst": _worst(accepted, False)}}
    round_1 = [dict(enumerate(r.get("rank_spearman_by_round") or [])).get(1) or {} for r in runs]
    out["rank_spearman_round_1"] = {rank: _median([by_rank.get(rank) for by_rank in round_1])
                                    for rank in REVIEW_RANKS}
    out["targets_met"] = targets_met(cell, runs, out)
    return out


def targets_met(cell: Cell, runs: list[dict[str, Any]], summary: dict[str, Any]) -> dict[str, bool]:
    """The issue's targets on the medians over the seeds: the cell's own (HEADLINE_TARGETS) and, for every cell,
    additions growing round on round and accepted labels within ACCEPTED_VERTEX_MM_MAX."""
    met: dict[str, bool] = {}
    for key, index, bound, threshold in HEADLINE_TARGETS.get(cell.name, ()):
        if key == "labels_per_human_hour":  # a figure of every round: the target's round named
            name, value = f"{key}_by_round_{index}", _median([_at_round(r, index) for r in runs])
        else:  # a summary figure whose name says its round
            name, value = key, summary[key]["median"]
        met[name] = value is not None and (value >= threshold if bound == "min" else value <= threshold)
    met["additions_grow"] = summary["additions_grow"] is True
    mm = summary["accepted_vertex_mm"]["median"]
    met["accepted_vertex_mm"] = mm is not None and mm <= ACCEPTED_VERTEX_MM_MAX
    return met


# --- the table and the plot ------------------------------------------------------------------------------------
def _num(value: float | None, fmt: str) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, fmt)


def _pair(figures: dict[str, float | None], fmt: str) -> str:
    return f"{_num(figures['median'], fmt)} / {_num(figures['worst'], fmt)}"


def markdown_table(cells: list[dict[str, Any]]) -> str:
    """One row per cell: median / worst seed of each figure."""
    head = ("| cell | runs (stopped) | labels / human h | labels / human h by round 2 | heuristic share by round 2 "
            "| true precision | additions per round (median) | MVNet mm, last round | accepted mm "
            "| round 1's review rank vs true error, Spearman: confidence / agreement (median) |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for c in cells:
        additions = " / ".join(_num(a, ".0f") for a in c["additions_per_round"]) or "-"
        lines.append(f"| {c['cell']} | {c['runs']} ({c['stopped']}) | {_pair(c['labels_per_human_hour'], '.1f')} "
                     f"| {_pair(c['labels_per_human_hour_by_round_2'], '.1f')} "
                     f"| {_pair(c['heuristic_share_by_round_2'], '.1%')} "
                     f"| {_pair(c['auto_accept_precision'], '.3f')} | {additions} "
                     f"| {_pair(c['mvnet_keypoint_mm'], '.1f')} | {_pair(c['accepted_vertex_mm'], '.2f')} "
                     f"| {' / '.join(_num(c['rank_spearman_round_1'][k], '.2f') for k in REVIEW_RANKS)} |")
    return "\n".join(lines)


def write_plot(cells: list[dict[str, Any]], runs: list[dict[str, Any]], path: Path) -> Path:
    """A PNG: per cell, the median labels per human hour over the run (bar) and each seed's (dots)."""
    import matplotlib  # deferred: only when the plot is drawn, its Agg backend chosen before pyplot loads

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(cells) + 2), 4.5), dpi=120)
    x = list(range(len(cells)))
    ax.bar(x, [c["labels_per_human_hour"]["median"] or 0.0 for c in cells], color="#4c72b0", alpha=0.7,
           label="median over the seeds")
    for i, c in enumerate(cells):
        seeds = [r["labels_per_human_hour"] for r in runs if r["cell"] == c["cell"]]
        ax.plot([i] * len(seeds), [s or 0.0 for s in seeds], "k.", label="one seed" if i == 0 else None)
    ax.set_xticks(x, [c["cell"] for c in cells], rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("labels per human hour (the run)")
    ax.set_title("bench sim-matrix: labels per human hour per cell")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


# --- the results file ------------------------------------------------------------------------------------------
def _write_atomically(path: Path, data: dict[str, Any]) -> None:
    """Replace the file whole, so an interruption leaves the previous version, never half of one."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def _load_results(path: Path, config: dict[str, Any], resume: bool) -> dict[str, Any]:
    """The results so far: a fresh file, or with `resume` the runs of an earlier matrix of the same config."""
    if not path.exists():
        return {"version": RESULTS_VERSION, "config": config, "runs": {}}
    if not resume:
        raise ValueError(f"{path} exists: pass --resume to finish that matrix, or another --out")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path} is not a sim-matrix results file ({exc}); pass another --out") from exc
    if not isinstance(data, dict) or data.get("version") != RESULTS_VERSION or not isinstance(data.get("runs"), dict):
        raise ValueError(f"{path} is not a sim-matrix results file of version {RESULTS_VERSION}; pass another --out")
    if isinstance(reviewer := (data.get("config") or {}).get("reviewer"), dict):
        reviewer.setdefault("discards_before_annotation", 0)  # a file from before the option: nobody discarded
        # (resumed with --reviewer-discards 0)
        reviewer.setdefault("round0_discard_floor", None)  # before that option: round 0 never discarded
    if isinstance(data.get("config"), dict):
        data["config"].setdefault("environment", {})  # a file from before it was recorded: taken as none set
    if data.get("config") != config:
        differ = sorted(k for k in set(config) | set(data.get("config") or {})
                        if config.get(k) != (data.get("config") or {}).get(k))
        raise ValueError(f"{path} was made with other settings ({', '.join(differ)} differ): resume it with the "
                         f"same options, or pass another --out")
    return data


def loop_environment(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The HANDLOOP_* settings in the environment that shape a run: setting name -> value as set, sorted; plumbing
    (PLUMBING_SETTINGS) and anything secret-like (NEVER_RECORDED) left out. Default environment: the `.env` file the
    settings read, overridden by os.environ (as the settings are)."""
    if environ is None:
        dot_env = Path(str(Settings.model_config.get("env_file") or ".env"))
        environ = {**{k: v or "" for k, v in dotenv_values(dot_env).items()}, **os.environ} if dot_env.is_file() \
            else os.environ
    found = {}
    for key, value in environ.items():
        if not key.upper().startswith(ENV_PREFIX):
            continue
        name = key[len(ENV_PREFIX):].lower()
        if name in Settings.model_fields and name not in PLUMBING_SETTINGS and not any(
                word in name for word in NEVER_RECORDED):
            found[name] = value
    return dict(sorted(found.items()))


def run_key(cell: Cell, seed: int) -> str:
    return f"{cell.name}/seed{seed}"


def run(*, cells: list[Cell], seeds: tuple[int, ...], out_dir: Path | None = None, resume: bool = False,
        quick: bool = False, rounds: int | None = None, frames: int | None = None,
        train_steps: int | None = None, handsegnet_steps: int | None = None,
        detector: str = "on", reviewer_discards: int = REVIEWER_DISCARDS,
        reviewer_round0_floor: int | None = REVIEWER_ROUND0_FLOOR, review_capacity: int | None = None,
        emit_json: bool = True) -> dict[str, Any]:
    """Run every (cell, seed) not yet in `<out_dir>/matrix.json`, one after the other, writing each as it finishes;
    then the per-cell summaries, the markdown table, `<out_dir>/matrix.png`, and (with `emit_json`) the JSON line.

    Args:
        cells, seeds: what to run (seeds other than UNSEEN_SEEDS are recorded as such: `seeds_unseen` false).
        quick: bench sim's QUICK plan (3 x 8 frames, tiny networks, 1 round) at the cells' widths: to check that
            the matrix works, not to judge the loop.
        rounds, frames: replace the plan's (default ROUNDS rounds; QUICK's with `quick`).
        train_steps, handsegnet_steps: a round's training steps (None: the issue's TRAIN_STEPS and
            HANDSEGNET_STEPS); the matrix is always step-counted, so its runs repeat on one machine.
        detector: "on" (round 0 pre-annotated, as users run the loop; refused where it cannot run) or "off".
        reviewer_discards: the simulated reviewers' `discards_before_annotation` (REVIEWER_DISCARDS; 0: every
            bad fit to the annotators); recorded in the results' config like the people.
        reviewer_round0_floor: the reviewers' `round0_discard_floor` (REVIEWER_ROUND0_FLOOR; None: round 0 never
            discards); recorded likewise.
        review_capacity: the stack's `review_capacity_per_round` (round 0's too), the fits the reviewers can verify
            in a round (None: the setting's default, the fixed policy); recorded in the stack settings.
    ValueError names a bad option, a results file of other settings, or a detector that cannot run.
    """
    started = time.perf_counter()
    if detector not in ("on", "off"):
        raise ValueError(f"detector must be on or off, not {detector!r}")
    reviewer = ReviewerConfig(discards_before_annotation=reviewer_discards,  # raises on a value out of range
                              round0_discard_floor=reviewer_round0_floor)
    if detector == "on" and (problem := preannotation.detector_problem()) is not None:
        raise ValueError(f"--detector on needs the pretrained detector: {problem} (or pass --detector off)")
    if not cells or not seeds:
        raise ValueError("the matrix needs at least one cell and one seed")
    base = sim.plan_for(quick=quick, rounds=ROUNDS if rounds is None and not quick else rounds, frames=frames,
                        train_steps=TRAIN_STEPS if train_steps is None else train_steps,
                        handsegnet_steps=HANDSEGNET_STEPS if handsegnet_steps is None else handsegnet_steps)
    if review_capacity is not None:
        if not 0 <= review_capacity <= MAX_REVIEW_CAPACITY:
            raise ValueError(f"review capacity must be in 0..{MAX_REVIEW_CAPACITY} samples a round, "
                             f"not {review_capacity}")
        base["settings"] = {**base["settings"], "review_capacity_per_round": review_capacity}
    out_dir = Path(out_dir) if out_dir else get_settings().data_dir.resolve() / "bench" / "sim-matrix"
    out_dir.mkdir(parents=True, exist_ok=True)
    results_path = out_dir / "matrix.json"
    def unseeded(config: Any) -> dict[str, Any]:  # the people's seed is the run's
        return {k: v for k, v in asdict(config).items() if k != "seed"}

    people = {name: unseeded(AnnotatorConfig(**noise)) for name, noise in PEOPLE.items()}
    config = json.loads(json.dumps({  # as the results file holds it, to compare on --resume
        "plan": {k: v for k, v in base.items() if k not in ("settings", "width")}, "stack_settings": base["settings"],
        "detector": detector, "quick": quick, "people": people, "proposals": PROPOSALS,
        "reviewer": unseeded(reviewer), "environment": loop_environment()}))
    results = _load_results(results_path, config, resume)
    todo = [(c, s) for c in cells for s in seeds if run_key(c, s) not in results["runs"]]
    with tqdm(total=len(cells) * len(seeds), initial=len(cells) * len(seeds) - len(todo), unit="run",
              desc="sim matrix", file=sys.stderr) as bar:
        for cell, seed in todo:
            bar.set_postfix_str(f"{cell.name} seed {seed}")
            plan = {**base, "width": cell.width_px}
            capture = sim.synthetic_capture(get_settings().data_dir.resolve() / "bench", plan["sequences"],
                                            plan["frames"], plan["width"], seed)
            work = out_dir / "runs" / f"{cell.name}-seed{seed}"
            if work.exists():  # an interrupted run of this matrix: its stack's database cannot be reused
                shutil.rmtree(work)
            summary = sim.simulate(capture, work, plan, detector=detector == "on", annotator=cell.annotator(seed),
                               reviewer=replace(reviewer, seed=seed), label=f"{cell.name} seed {seed}",
                                   leave=False)
            results["runs"][run_key(cell, seed)] = {**run_record(cell, seed, summary, work),
                                                    "commit": git_commit(), "finished_at": time.time()}
            _write_atomically(results_path, results)
            bar.update(1)
    runs = [results["runs"][run_key(c, s)] for c in cells for s in seeds]
    summaries = [cell_summary(c, [r for r in runs if r["cell"] == c.name]) for c in cells]
    table = markdown_table(summaries)
    plot = write_plot(summaries, runs, out_dir / "matrix.png")
    print(table)
    record = {"cells": summaries, "runs": runs, "table": table, "results": str(results_path), "plot": str(plot),
              "seeds": list(seeds), "seeds_unseen": set(seeds) <= set(UNSEEN_SEEDS),
              "targets": {"headline": {k: [list(t) for t in v] for k, v in HEADLINE_TARGETS.items()},
                          "accepted_vertex_mm_max": ACCEPTED_VERTEX_MM_MAX, "on": "the median over the seeds"}}
    settings = {**config, "cells": [c.name for c in cells], "seeds": list(seeds), "out_dir": str(out_dir)}
    return emit("sim-matrix", record, settings, started) if emit_json else record
