"""The bootstrap simulation: D_0 ... D_n through the real server and workers, with simulated people.

The capture is imported as one project with every sample unlabeled; the admin queues the initial set
(every k-th frame of each training sequence, spread over subjects and motions) for annotation. Round 0:
simulated annotators click it, the workers fit, simulated reviewers verify (bad fits go back for clicks): D_0.
With the detector (`BootstrapConfig.detector`), the admin pre-annotates the initial set instead (issue 15): the
pretrained detector -> triangulation -> fit on each, the reviewers first verify what the queue policy picks,
the rest and what they send back reach the annotators (with the detector's keypoints as proposals). Round
i >= 1: the admin launches a round through the API (the workers train MVNet and HandSegNet on D_{i-1},
predict and fit the rest, accept by the heuristic and queue the review); the reviewers verify the queue,
the annotators click what was sent back, and so on until both queues are empty: D_i. After each round the
report reads the server's statistics and records (admin exports) and compares every accepted fit and
every MVNet prediction with the ground truth.
"""

from __future__ import annotations

import logging
import math
import secrets
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from backend.services.review.verification import REVIEW_RANKS, review_score
from backend.services.rounds.preannotation import DEFAULT_REST, RESTS
from backend.simulation.annotator import AnnotatorConfig, SimulatedAnnotator
from backend.simulation.client import ApiClient, ApiError
from backend.simulation.costs import PAPER_FULL_ANNOTATION_S, HumanLedger, UnitCosts
from backend.simulation.ranking import rank_quality
from backend.simulation.reviewer import ReviewerConfig, SimulatedReviewer
from backend.simulation.team import SimulationTimeoutError, Team, TeamWork, wait_for_job, wait_until_idle
from backend.simulation.truth import SEQUENCE_KINDS, GroundTruthIndex
from workers.capture import read_capture
from workers.evaluation import summarise_errors

log = logging.getLogger(__name__)

STREAMS = ("heuristic", "manual", "annotated")
ROUND0_FRAMES = ("all", "initial")  # with the detector: every training frame pre-annotated, or the initial set


@dataclass(frozen=True)
class BootstrapConfig:
    """A simulation run.

    Attributes:
        rounds: bootstrap rounds after D_0 (D_0 ... D_rounds).
        annotators, reviewers: simulated accounts of each role.
        annotator, reviewer: how they work (each account gets its own random stream).
        costs: seconds per click, mask correction and verification.
        auto_accept_max_mm: a heuristic accept counts as correct when its true mean vertex error is at most this.
        round_timeout_s: longest wait for one round's job (and for the fits queued by people).
        poll_s: job polling interval.
        project: name of the project the capture is imported as.
        detector: round 0 pre-annotated by the pretrained detector (the server must have its model files);
            None: when the server can run it.
        audit_share: share of each stream's accepts the server audits blind (review.label_audits; 0: none), with
            `audit_seed`; `precision_target`: the server's "at most this share of auto-accepts wrong" (None: off).
            The run's `label_quality` compares the audits' estimates with the truth (`label_quality`).
        gold_labels, gold_share: after D_0, the admin marks up to this many accepted labels gold (truly right: under
            half the reviewers' accept limit), slipped into the reviewers' queues at `gold_share`; their agreement is
            compared with what they were given (1 - their error rate).
        agreement_share: the share of annotated samples the server has annotated twice, blind (issue 40); the run's
            `label_quality["agreement"]` compares the 2D disagreement with the annotators' click noise.
        round0_rest: with the detector, what happens to the initial set's samples the review policy does not
            pick: "keep" (they stay for round 1's MVNet, as the paper leaves the unpicked samples of every round
            and the issue routes round 0: only fits sent back are annotated) or "annotate" (annotators click
            them in round 0; D_0 is then at most half verified, since the policy picks from the median up).
        round0_frames: with the detector, which training frames the admin pre-annotates in round 0: "all" (the
            detector's heuristic accepts what it can, reviewers see the rest by the queue policy) or "initial" (the
            initial set only, every k-th frame, as before issue 37's detector heuristic).
    """

    rounds: int = 4
    annotators: int = 2
    reviewers: int = 1
    annotator: AnnotatorConfig = field(default_factory=AnnotatorConfig)
    reviewer: ReviewerConfig = field(default_factory=ReviewerConfig)
    costs: UnitCosts = field(default_factory=UnitCosts)
    auto_accept_max_mm: float = 10.0
    round_timeout_s: float = 3600.0
    poll_s: float = 1.0
    project: str = "sim"
    detector: bool | None = False
    round0_rest: str = DEFAULT_REST
    round0_frames: str = "all"
    audit_share: float = 0.0
    audit_seed: int = 0
    precision_target: float | None = None
    gold_labels: int = 0
    gold_share: float = 0.0
    agreement_share: float = 0.0

    def __post_init__(self) -> None:
        if self.round0_rest not in RESTS:
            raise ValueError(f"round0_rest must be one of {list(RESTS)}, not {self.round0_rest!r}")
        if self.round0_frames not in ROUND0_FRAMES:
            raise ValueError(f"round0_frames must be one of {list(ROUND0_FRAMES)}, not {self.round0_frames!r}")
        if not 0 <= self.rounds <= 50:
            raise ValueError(f"rounds must be in 0..50, not {self.rounds}")
        if not (1 <= self.annotators <= 100 and 1 <= self.reviewers <= 100):
            raise ValueError("annotators and reviewers must each be in 1..100")
        if not 0 <= self.agreement_share <= 1:
            raise ValueError(f"agreement_share must be in [0, 1], not {self.agreement_share}")
        if not (0 <= self.audit_share <= 1 and 0 <= self.gold_share <= 1):
            raise ValueError(f"audit_share and gold_share must be in [0, 1], not {self.audit_share}, {self.gold_share}")
        if not 0 <= self.gold_labels <= 10_000:
            raise ValueError(f"gold_labels must be in 0..10000, not {self.gold_labels}")
        if self.precision_target is not None and not 0 < self.precision_target < 1:
            raise ValueError(f"precision_target must be in (0, 1) or None, not {self.precision_target}")
        if not self.round_timeout_s > 0 or not self.poll_s > 0:
            raise ValueError("round_timeout_s and poll_s must be positive")


@dataclass
class RoundReport:
    """One round as measured (JSON-ready). Errors in millimetres; None where nothing was measured."""

    index: int
    added: dict[str, int]
    added_total: int
    dataset_size: int
    human_hours: float
    human_hours_cumulative: float
    labels_per_human_hour: float | None  # this round's added labels over its human hours
    verified_share: float | None  # share of the round's labels that came from verification alone (D^m)
    effort: dict[str, int]
    auto_accepted: int
    auto_accept_precision: float | None
    accepted_vertex_mm: float | None
    accepted_keypoint_mm: float | None
    accepted_vertex_mm_by_stream: dict[str, float | None]
    added_vertex_mm: float | None
    reviewed: int
    reviewed_vertex_mm: float | None
    reviewed_vertex_mm_median: float | None
    reviewed_from_predictions: int
    reviewed_from_predictions_median_mm: float | None
    reviewed_after_annotation_median_mm: float | None
    mvnet_predictions: int
    mvnet_keypoint_mm: float | None
    mvnet_keypoint_mm_median: float | None
    mvnet_auc: float | None
    # The same split by sequence kind ("green_screen", "cluttered"): each {predictions, keypoint_mm,
    # keypoint_mm_median, auc}; the cluttered evaluation sequences have no chroma key to lift from.
    mvnet_by_kind: dict[str, dict[str, Any]]
    round_job: dict[str, Any] | None
    minutes: float
    bookkeeping_ok: bool
    preannotation: dict[str, Any] | None = None  # round 0 with the detector: the pre-annotation job's result
    # Rounds >= 1: how well each review rank orders the round's fits from predictions that the heuristic did not
    # accept by their true error (backend.simulation.ranking.rank_quality); None without such fits.
    rank_quality: dict[str, Any] | None = None


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def mvnet_errors_summary(errors_m: np.ndarray | None) -> dict[str, Any]:
    """MVNet's keypoint errors (S, 21) metres -> {predictions, keypoint_mm (mean), keypoint_mm_median (over all
    keypoints), auc (3D PCK 0-50 mm)}; None figures without predictions."""
    if errors_m is None or len(errors_m) == 0:
        return {"predictions": 0, "keypoint_mm": None, "keypoint_mm_median": None, "auc": None}
    return {"predictions": len(errors_m), "keypoint_mm": float(errors_m.mean() * 1000),
            "keypoint_mm_median": float(np.median(errors_m) * 1000), "auc": summarise_errors(errors_m).auc}


class BootstrapSimulation:
    """Drives one server through the bootstrap with simulated people.

    Args:
        http: a client bound to the server (httpx.Client(base_url=...), or a TestClient in tests).
        admin: an admin's API client.
        config: the run.
        wait_for_workers: blocks until the workers have done what people queued (default: poll the jobs).
        run_round: launches-and-waits for a round job (default: poll its job); returns the final job.
        run_job: waits for another job (the pre-annotation; default: poll it); returns the final job.
        on_round: called with each finished RoundReport (progress).
    """

    def __init__(self, http: httpx.Client, admin: ApiClient, config: BootstrapConfig, *,
                 wait_for_workers: Callable[[], None] | None = None,
                 run_round: Callable[[int], dict[str, Any]] | None = None,
                 run_job: Callable[[int], dict[str, Any]] | None = None,
                 on_round: Callable[[RoundReport], None] | None = None) -> None:
        self.http = http
        self.admin = admin
        self.config = config
        self.ledger = HumanLedger(costs=config.costs)
        self.wait_for_workers = wait_for_workers or (
            lambda: wait_until_idle(admin, timeout_s=config.round_timeout_s, poll_s=config.poll_s))
        self.run_round = run_round or (
            lambda job_id: wait_for_job(admin, job_id, timeout_s=config.round_timeout_s, poll_s=config.poll_s,
                                        on_progress=lambda j: log.info("round job %d: %.0f%% %s", j["id"],
                                                                       100 * j["progress"], j["message"])))
        self.run_job = run_job or (
            lambda job_id: wait_for_job(admin, job_id, timeout_s=config.round_timeout_s, poll_s=config.poll_s,
                                        on_progress=lambda j: log.info("%s job %d: %.0f%% %s", j["kind"], j["id"],
                                                                       100 * j["progress"], j["message"])))
        self.on_round = on_round
        self.truth: GroundTruthIndex | None = None
        self.initial_set: list[int] = []
        self.gold: list[int] = []
        self.project_id: int | None = None
        self.detector_on = bool(config.detector)  # settled by `prepare` when config.detector is None
        self.preannotation: dict[str, Any] | None = None
        self._errors: dict[int, tuple[float, float]] = {}  # fit id -> (vertex mm, keypoint mm)
        self._previous_size = 0

    # --- set-up ----------------------------------------------------------------------------------------
    def _people(self, truth: GroundTruthIndex) -> Team:
        cfg = self.config
        run = secrets.token_hex(3)

        def account(role: str, i: int) -> ApiClient:
            email, password = f"sim-{role}-{i}-{run}@simulation.local", secrets.token_urlsafe(12)
            self.admin.create_user(email, password, role, f"simulated {role} {i}")
            return ApiClient.sign_in(self.http, email, password)

        annotators = [SimulatedAnnotator(f"annotator{i}", account("annotator", i), truth, self.ledger,
                                         AnnotatorConfig(**{**asdict(cfg.annotator), "seed": cfg.annotator.seed + i}))
                      for i in range(cfg.annotators)]
        reviewers = [SimulatedReviewer(f"reviewer{i}", account("reviewer", i), truth, self.ledger,
                                       ReviewerConfig(**{**asdict(cfg.reviewer), "seed": cfg.reviewer.seed + i}))
                     for i in range(cfg.reviewers)]
        return Team(annotators, reviewers, max_annotation_passes=cfg.reviewer.max_annotation_attempts + 1)

    def prepare(self, capture_dir: Path, initial_every: int) -> Team:
        """Import the capture (unlabeled), queue the initial set for annotation (with the detector: leave it to
        `preannotate`), create the accounts."""
        if initial_every < 2:
            raise ValueError(f"initial_every must be at least 2 (all frames in D_0 leave nothing to bootstrap), "
                             f"not {initial_every}")
        project = self.config.project
        if self.config.detector is not False:  # refused before anything is imported where the server cannot run it
            status = self.admin.preannotation()
            if self.config.detector and not status["available"]:
                raise ValueError(f"the simulation with the detector needs it on the server: {status['reason']}")
            self.detector_on = bool(status["available"])
            if not self.detector_on:
                log.info("detector off: %s", status["reason"])
        # The server's quality settings as the run's (its default share would audit 5 % of every run).
        # The auditors' error rate is the simulated reviewers' own (gold samples would measure it on a real team).
        self.admin.set_quality(audit_share=self.config.audit_share, audit_seed=self.config.audit_seed,
                               precision_target=self.config.precision_target,
                               auditor_error_rate=min(self.config.reviewer.error_rate, 0.49),
                               gold_share=self.config.gold_share,
                               agreement_share=self.config.agreement_share)
        imported = self.admin.import_capture(str(capture_dir), project, queue_for_annotation=False)
        self.project_id = int(imported["project_id"])
        samples = self.admin.sample_index(project=project)["samples"]
        initial = [s["sample_id"] for s in samples if s["split"] == "train" and s["frame_index"] % initial_every == 0]
        if not initial:
            raise ValueError(f"{capture_dir}: no training frames for the initial set")
        if self.detector_on and self.config.round0_frames == "all":
            initial = [s["sample_id"] for s in samples if s["split"] == "train"]
        self.initial_set = initial if self.detector_on else self.admin.queue_for_annotation(initial)
        self.truth = GroundTruthIndex({project: read_capture(capture_dir, check_images=False)}, samples)
        return self._people(self.truth)

    def preannotate(self) -> dict[str, Any]:
        """Round 0 with the detector: pre-annotate the chosen frames (`round0_frames`); the final job."""
        launched = self.admin.preannotate(int(self.project_id), self.initial_set, rest=self.config.round0_rest)
        job = self.run_job(launched["job_id"])
        self.preannotation = {k: job.get(k) for k in ("id", "state", "message", "error", "result")}
        return job

    # --- the run ---------------------------------------------------------------------------------------
    def run(self, capture_dir: Path, initial_every: int) -> dict[str, Any]:
        """Run D_0 ... D_rounds on the capture; returns the summary (see `summary`).

        Args:
            capture_dir: a synthetic capture the server can read (it is imported by path).
            initial_every: the initial set is every k-th frame of each training sequence (k >= 2).
        """
        started = time.perf_counter()
        team = self.prepare(capture_dir, initial_every)
        reports: list[RoundReport] = []
        stopped: dict[str, Any] | None = None  # {"round", "reason"} where the run ends before its last round
        for index in range(self.config.rounds + 1):
            round_started = time.perf_counter()
            job_info = None
            try:
                if index > 0:
                    try:
                        launched = self.admin.launch_round(note=f"bootstrap simulation round {index}")
                    except ApiError as exc:
                        if exc.status != 409:
                            raise
                        # The server refused to open the round (e.g. nothing accepted yet): D_index does not exist,
                        # so there is no round to measure; the rounds so far are the run.
                        stopped = {"round": index, "reason": str(exc)}
                        break
                    job = self.run_round(launched["job_id"])
                    job_info = {k: job.get(k) for k in ("id", "state", "message", "error")}
                    job_info["heuristic"] = (job.get("result") or {}).get("heuristic")  # evaluated, accepted
                    if job["state"] != "succeeded":
                        stopped = {"round": index, "reason": f"the round job ended '{job['state']}': "
                                                             f"{job.get('error') or job['message']}"}
                        self._report_stopped_round(reports, index, job_info, round_started)
                        break
                    self.wait_for_workers()
                    self.admin.build_review_queue()  # the round job built it; this adds fits that finished later
                elif self.detector_on:
                    job = self.preannotate()  # reported as the round's `preannotation`, not as a round job
                    if job["state"] != "succeeded":
                        stopped = {"round": 0, "reason": f"the pre-annotation job ended '{job['state']}': "
                                                         f"{job.get('error') or job['message']}"}
                        self._report_stopped_round(reports, index, job_info, round_started)
                        break
                work = team.work_until_done(index, self.wait_for_workers, labels_so_far=self.dataset_size_now)
            except (ApiError, SimulationTimeoutError) as exc:
                # The rounds measured so far are still worth reporting; say where and why it stopped.
                stopped = {"round": index, "reason": str(exc)}
                self._report_stopped_round(reports, index, job_info, round_started)
                break
            reports.append(self._report(index, job_info, round_started, work))
            if index == 0 and self.config.gold_labels:
                self.mark_gold(self.config.gold_labels)
            self._announce(reports[-1])
        if stopped:
            log.error("stopped in round %d: %s", stopped["round"], stopped["reason"])
        return self.summary(reports, time.perf_counter() - started, stopped)

    def dataset_size_now(self) -> int:
        """Accepted labels so far, the open round's included (the server's statistics)."""
        rounds = self.admin.statistics()["rounds"]
        return int(rounds[-1]["dataset_size_after"]) if rounds else 0

    def _report_stopped_round(self, reports: list[RoundReport], index: int, job_info: dict[str, Any] | None,
                              started: float) -> None:
        """The round the run stopped in, where the server can still report it; a round it never opened (its
        exports answer 404) has nothing to report."""
        try:
            reports.append(self._report(index, job_info, started, None))
        except ApiError as exc:
            log.warning("round %d is not reported: %s", index, exc)

    def _announce(self, report: RoundReport) -> None:
        log.info("D_%d: %d samples (+%d: %s), %.2f human hours, accepted %.2f mm", report.index, report.dataset_size,
                 report.added_total, report.added, report.human_hours,
                 report.accepted_vertex_mm if report.accepted_vertex_mm is not None else float("nan"))
        if report.rank_quality is not None:
            q = report.rank_quality
            ranks = ", ".join(f"{rank} {'-' if f['spearman'] is None else format(f['spearman'], '.2f')}"
                              for rank, f in q["by_rank"].items())
            log.info("D_%d: review ranks against the true error of %d fits (%.0f %% under %g mm), Spearman: %s",
                     report.index, q["fits"], 100 * (q["good_share"] or 0.0), q["good_below_mm"], ranks)
        if self.on_round is not None:
            self.on_round(report)

    # --- measuring -------------------------------------------------------------------------------------
    def _fit_errors(self, members: list[dict]) -> None:
        """True errors of the fits of `members` (rows with "sample_id" and "fit": {"id", "params"}), cached by fit
        id: the dataset's members and the predictions' fits share them."""
        todo = [m for m in members if m["fit"] and m["fit"]["id"] not in self._errors and m["sample_id"] in self.truth]
        errors = self.truth.fit_errors([m["sample_id"] for m in todo], [m["fit"]["params"] for m in todo])
        for member, error in zip(todo, errors, strict=True):
            self._errors[member["fit"]["id"]] = (error.vertex_mm, error.keypoint_mm)

    def _report(self, index: int, job: dict[str, Any] | None, started: float, work: TeamWork | None) -> RoundReport:
        stats = {r["index"]: r for r in self.admin.statistics()["rounds"]}
        row = stats.get(index, {"added": dict.fromkeys(STREAMS, 0), "added_total": 0,
                                "dataset_size_after": self._previous_size})
        members = self.admin.dataset(up_to_round=index)["samples"]
        self._fit_errors(members)

        def errors_of(selected: list[dict], which: int = 0) -> list[float]:
            known = [m["fit"]["id"] for m in selected if m["fit"] and m["fit"]["id"] in self._errors]
            return [self._errors[fit_id][which] for fit_id in known]

        this_round = [m for m in members if m["round"] == index]
        heuristic = [m for m in this_round if m["stream"] == "heuristic"]
        heuristic_mm = errors_of(heuristic)
        predictions = [p for p in self.admin.predictions(round_index=index)["predictions"]
                       if p["sample_id"] in self.truth]
        mvnet_errors = np.array([np.linalg.norm(np.asarray(p["keypoints_m"])
                                                - self.truth.truth(p["sample_id"]).keypoints_3d, axis=1)
                                 for p in predictions]) if predictions else None
        kinds = np.array([self.truth.sequence_kind(p["sample_id"]) for p in predictions])
        mvnet = mvnet_errors_summary(mvnet_errors)
        by_heuristic = {m["sample_id"] for m in heuristic}
        candidates = [p for p in predictions if p["fit"] is not None and p["sample_id"] not in by_heuristic]
        size = int(row["dataset_size_after"])
        # D_{i+1} = D_i + D^h + D^m + D^l: the server's cumulative count, its per-stream additions and the
        # dataset export must agree.
        bookkeeping_ok = (size == self._previous_size + int(row["added_total"]) == len(members)
                          and int(row["added_total"]) == sum(int(row["added"][s]) for s in STREAMS)
                          == len(this_round))
        self._previous_size = size
        hours = self.ledger.hours(index)
        added_total = int(row["added_total"])
        reviews = work.reviews if work is not None else []
        reviewed_mm = [r.vertex_mm for r in reviews]
        from_predictions = [r.vertex_mm for r in reviews if not r.after_annotation]
        after_annotation = [r.vertex_mm for r in reviews if r.after_annotation]
        return RoundReport(
            index=index, added={s: int(row["added"][s]) for s in STREAMS}, added_total=int(row["added_total"]),
            dataset_size=size, human_hours=hours,
            human_hours_cumulative=sum(self.ledger.hours(i) for i in range(index + 1)),
            labels_per_human_hour=added_total / hours if hours > 0 else None,
            verified_share=int(row["added"]["manual"]) / added_total if added_total else None,
            effort=vars(self.ledger.effort(index)), auto_accepted=len(heuristic),
            auto_accept_precision=(float(np.mean(np.asarray(heuristic_mm) <= self.config.auto_accept_max_mm))
                                   if heuristic_mm else None),
            accepted_vertex_mm=_mean(errors_of(members)), accepted_keypoint_mm=_mean(errors_of(members, 1)),
            accepted_vertex_mm_by_stream={s: _mean(errors_of([m for m in members if m["stream"] == s]))
                                          for s in STREAMS},
            added_vertex_mm=_mean(errors_of(this_round)), reviewed=len(reviewed_mm),
            reviewed_vertex_mm=_mean(reviewed_mm),
            reviewed_vertex_mm_median=_median(reviewed_mm), reviewed_from_predictions=len(from_predictions),
            reviewed_from_predictions_median_mm=_median(from_predictions),
            reviewed_after_annotation_median_mm=_median(after_annotation),
            mvnet_predictions=len(predictions), mvnet_keypoint_mm=mvnet["keypoint_mm"],
            mvnet_keypoint_mm_median=mvnet["keypoint_mm_median"], mvnet_auc=mvnet["auc"],
            mvnet_by_kind={kind: mvnet_errors_summary(mvnet_errors[kinds == kind] if predictions else None)
                           for kind in SEQUENCE_KINDS},
            round_job=job, minutes=(time.perf_counter() - started) / 60, bookkeeping_ok=bookkeeping_ok,
            preannotation=self.preannotation if index == 0 else None,
            rank_quality=self._rank_quality(candidates) if candidates else None)

    def _rank_quality(self, candidates: list[dict]) -> dict[str, Any]:
        """`rank_quality` over a round's predictions whose fits did not join the dataset this round."""
        self._fit_errors(candidates)
        scores = {rank: [review_score(rank, p["mean_confidence"], p["fit"]["heuristic"]) for p in candidates]
                  for rank in REVIEW_RANKS}
        return rank_quality([self._errors[p["fit"]["id"]][0] for p in candidates], scores,
                            self.config.reviewer.accept_below_mm)

    def summary(self, reports: list[RoundReport], seconds: float, stopped: dict[str, Any] | None) -> dict[str, Any]:
        """The run's figures: per round, and over the run (the keys `handloop bench sim` reports). `stopped`:
        {"round": index, "reason": text} where the run ended before its last round, else None."""
        members = self.admin.dataset()["samples"]
        self._fit_errors(members)
        heuristic = [self._errors[m["fit"]["id"]][0] for m in members
                     if m["stream"] == "heuristic" and m["fit"] and m["fit"]["id"] in self._errors]
        vertex = [self._errors[m["fit"]["id"]][0] for m in members if m["fit"] and m["fit"]["id"] in self._errors]
        size = reports[-1].dataset_size if reports else 0
        hours = self.ledger.hours()
        paper_per_hour = 3600.0 / PAPER_FULL_ANNOTATION_S
        return {
            "rounds": [asdict(r) for r in reports],
            "rounds_completed": sum(1 for r in reports if r.round_job and r.round_job["state"] == "succeeded"),
            "initial_set": len(self.initial_set),
            "dataset_size": size,
            "auto_accepted": len(heuristic),
            "auto_accept_precision": float(np.mean(np.asarray(heuristic) <= self.config.auto_accept_max_mm))
            if heuristic else None,
            "accepted_vertex_mm": _mean(vertex),
            "human_hours": hours,
            "labels_per_human_hour": size / hours if hours > 0 else None,
            "paper_procedure": {
                "seconds_per_sample": PAPER_FULL_ANNOTATION_S, "labels_per_human_hour": paper_per_hour,
                "human_hours_for_the_same_labels": size * PAPER_FULL_ANNOTATION_S / 3600.0},
            "minutes": seconds / 60,
            "bookkeeping_ok": all(r.bookkeeping_ok for r in reports),
            "failure": None if stopped is None else f"round {stopped['round']}: {stopped['reason']}",
            "stopped": stopped,
            "detector": self.detector_on,
            "d0_verified_share": reports[0].verified_share if reports else None,
            "label_quality": self.label_quality(members),
            "config": {"rounds": self.config.rounds, "annotators": self.config.annotators,
                       "reviewers": self.config.reviewers, "annotator": asdict(self.config.annotator),
                       "reviewer": asdict(self.config.reviewer), "costs": asdict(self.config.costs),
                       "auto_accept_max_mm": self.config.auto_accept_max_mm, "detector": self.detector_on,
                       "audit_share": self.config.audit_share, "audit_seed": self.config.audit_seed,
                       "precision_target": self.config.precision_target, "gold_labels": self.config.gold_labels,
                       "gold_share": self.config.gold_share},
        }

    def mark_gold(self, count: int) -> list[int]:
        """Mark up to `count` accepted labels gold, the truly right ones (under half the reviewers' accept limit)."""
        members = self.admin.dataset()["samples"]
        self._fit_errors(members)
        limit = self.config.reviewer.accept_below_mm / 2
        right = [m["sample_id"] for m in members if m["fit"] and self._errors.get(m["fit"]["id"], (1e9,))[0] < limit]
        for sample_id in right[:count]:
            self.admin.mark_gold(sample_id)
        self.gold = right[:count]
        return self.gold

    def label_quality(self, members: list[dict]) -> dict[str, Any]:
        """Per stream, the server's audit estimate (corrected for the auditors' error rate; `_raw`: as called) of the
        share of accepted labels that are wrong beside the true
        share (a label is wrong when its fit's mean vertex error exceeds `auto_accept_max_mm`): over every label the
        stream accepted (those in the dataset and those audits took out), over the audited ones alone, and over the
        dataset as it is now; whether the interval holds the true share, and whether the precision target (the
        run's, else the issue's 2 %) is met on the true labels."""
        # Gold looks judge the reviewers, not the labels (a rejected gold label stays): audits only.
        audits = [a for a in self.admin.label_audits()
                  if a.get("kind", "audit") == "audit" and a["sample_id"] in self.truth and a["fit"]]
        estimates = self.admin.quality()["streams"]
        self._fit_errors([{"sample_id": a["sample_id"], "fit": a["fit"]} for a in audits])
        limit = self.config.auto_accept_max_mm
        target = self.config.precision_target if self.config.precision_target is not None else 0.02

        def wrong_share(fit_ids: set[int]) -> float | None:
            known = [self._errors[f][0] > limit for f in fit_ids if f in self._errors]
            return float(np.mean(known)) if known else None

        out: dict[str, Any] = {}
        for stream in STREAMS:
            present = {m["fit"]["id"] for m in members if m["stream"] == stream and m["fit"]}
            audited = {a["fit"]["id"] for a in audits if a["stream"] == stream and a["state"] == "done"}
            removed = {a["fit"]["id"] for a in audits if a["stream"] == stream and a["verdict"] == "wrong"}
            true_rate = wrong_share(present | removed)
            estimate = estimates.get(stream) or {}
            ci = estimate.get("error_rate_corrected_ci95")  # for the auditors' error rate (the reviewers')
            out[stream] = {
                "labels": len(present | removed), "audited": estimate.get("audited", 0),
                "audit_error_rate": estimate.get("error_rate_corrected"), "audit_error_rate_ci95": ci,
                "audit_error_rate_raw": estimate.get("error_rate"),
                "audit_error_rate_raw_ci95": estimate.get("error_rate_ci95"),
                "true_error_rate": true_rate, "true_error_rate_audited": wrong_share(audited),
                "true_error_rate_after_audits": wrong_share(present),
                "ci_holds_true": None if ci is None or true_rate is None else bool(ci[0] <= true_rate <= ci[1]),
                "precision_target": target,
                "target_met_true": None if true_rate is None else bool(true_rate <= target),
                "wrong_above_mm": limit}
        given = 1 - self.config.reviewer.error_rate
        out["gold"] = [{**g, "given_agreement": given, "ci_holds_given": None if g["agreement_ci95"] is None
                        else bool(g["agreement_ci95"][0] <= given <= g["agreement_ci95"][1])}
                       for g in self.admin.quality()["gold"]]
        out["agreement"] = self._agreement_against_given(self.admin.quality()["agreement"])
        return out

    def _agreement_against_given(self, figures: dict[str, Any]) -> dict[str, Any]:
        """The server's agreement figures beside what the annotators were given: two clicks with Gaussian noise of
        sigma px per coordinate lie sigma * sqrt(pi) apart on average (their difference has sigma * sqrt(2) per
        coordinate; a Rayleigh distance's mean). Swapped fingertips add far larger distances: the comparison holds
        for people who swap none (`swap_probability` 0); with swaps it is shown, not judged."""
        sigma = self.config.annotator.click_sigma_px
        given = sigma * math.sqrt(math.pi)
        ci = figures.get("keypoint_px_ci95")
        judged = ci is not None and self.config.annotator.swap_probability == 0
        return {"pairs": figures.get("pairs"), "single": figures.get("single"), "waiting": figures.get("waiting"),
                "keypoint_px_mean": figures.get("keypoint_px_mean"), "keypoint_px_ci95": ci,
                "mean_mm": figures.get("mean_mm"), "given_click_sigma_px": sigma,
                "given_swap_probability": self.config.annotator.swap_probability, "given_px_mean": given,
                "ci_holds_given": bool(ci[0] <= given <= ci[1]) if judged else None}
