"""A team of simulated annotators and reviewers working the server's queues until nothing is left, and
waiting for the workers' jobs in between (fits queued by submissions, rounds)."""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from backend.simulation.annotator import AnnotationOutcome, SimulatedAnnotator
from backend.simulation.client import ApiClient
from backend.simulation.reviewer import ReviewOutcome, SimulatedReviewer

log = logging.getLogger(__name__)

FINAL_JOB_STATES = ("succeeded", "failed", "cancelled")


class SimulationTimeoutError(TimeoutError):
    """The server's jobs did not finish in time."""


def wait_for_job(admin: ApiClient, job_id: int, *, timeout_s: float, poll_s: float = 1.0,
                 on_progress: Callable[[dict], None] | None = None) -> dict:
    """Poll a job until it is final; returns its last state."""
    deadline = time.monotonic() + timeout_s
    last = None
    while True:
        job = admin.job(job_id)
        if on_progress is not None and (job["progress"], job["message"]) != last:
            on_progress(job)
            last = (job["progress"], job["message"])
        if job["state"] in FINAL_JOB_STATES:
            return job
        if time.monotonic() > deadline:
            raise SimulationTimeoutError(f"job {job_id} ({job['kind']}) still {job['state']} after {timeout_s:.0f} s: "
                                    f"{job['message']}")
        time.sleep(poll_s)


def wait_until_idle(admin: ApiClient, *, timeout_s: float, poll_s: float = 1.0) -> None:
    """Poll until no job is queued or running."""
    deadline = time.monotonic() + timeout_s
    while True:
        busy = admin.jobs(state="queued", limit=1) + admin.jobs(state="running", limit=1)
        if not busy:
            return
        if time.monotonic() > deadline:
            raise SimulationTimeoutError(f"jobs still queued or running after {timeout_s:.0f} s, e.g. job "
                                    f"{busy[0]['id']} ({busy[0]['kind']}, {busy[0]['state']})")
        time.sleep(poll_s)


@dataclass
class TeamWork:
    """What a team did in one call of `work_until_done`."""

    annotations: list[AnnotationOutcome] = field(default_factory=list)
    reviews: list[ReviewOutcome] = field(default_factory=list)
    passes: int = 0
    stuck_samples: set[int] = field(default_factory=set)


class Team:
    """Annotators and reviewers taking turns on the queues (one request at a time: human time is counted
    with unit costs, not measured, so parallel people would only add load)."""

    def __init__(self, annotators: Sequence[SimulatedAnnotator], reviewers: Sequence[SimulatedReviewer], *,
                 max_annotation_passes: int = 3) -> None:
        if not annotators or not reviewers:
            raise ValueError("a team needs at least one annotator and one reviewer")
        self.annotators = list(annotators)
        self.reviewers = list(reviewers)
        self.max_annotation_passes = max_annotation_passes
        self.annotation_attempts: Counter[int] = Counter()
        self.discards: Counter[int] = Counter()

    def annotate_all(self, round_index: int, work: TeamWork, limit: int | None = None) -> int:
        """Annotators take tasks in turn until none of them gets one (or `limit` submissions): a sample waiting for an
        agreement's second look is never handed to its first annotator, so one may find nothing while another can."""
        done, turn, idle = 0, 0, 0
        while (limit is None or done < limit) and idle < len(self.annotators):
            give_up = frozenset(s for s, n in self.annotation_attempts.items() if n >= self.max_annotation_passes)
            outcome = self.annotators[turn % len(self.annotators)].annotate_next(
                round_index, give_up, frozenset(self.annotation_attempts))
            turn += 1
            if outcome is None:
                idle += 1
                continue
            idle = 0
            self.annotation_attempts[outcome.sample_id] += 1
            work.annotations.append(outcome)
            done += 1
        work.stuck_samples |= {s for s, n in self.annotation_attempts.items() if n >= self.max_annotation_passes}
        return done

    def review_all(self, round_index: int, work: TeamWork, labels_so_far: Callable[[], int] | None = None) -> int:
        """Reviewers take tasks in turn until none of them gets one (an audit is never handed to the reviewer who
        accepted the label, so one may find nothing while another still can). `labels_so_far`: the dataset's size
        now, for the reviewers' round-0 discard floor."""
        done, turn, idle = 0, 0, 0
        while idle < len(self.reviewers):
            outcome = self.reviewers[turn % len(self.reviewers)].review_next(round_index, self.annotation_attempts,
                                                                             self.discards, labels_so_far)
            turn += 1
            if outcome is None:
                idle += 1
                continue
            idle = 0
            if outcome.decision == "discard":
                self.discards[outcome.sample_id] += 1
            work.reviews.append(outcome)
            done += 1
        return done

    def work_until_done(self, round_index: int, wait: Callable[[], None], *, max_passes: int = 20,
                        annotation_limit: int | None = None,
                        labels_so_far: Callable[[], int] | None = None) -> TeamWork:
        """Annotate, wait for the fits, review; again while either queue had work.

        Args:
            wait: blocks until the workers have processed what was queued (e.g. `wait_until_idle`).
            annotation_limit: most submissions in the first pass (e.g. the size of D_0's budget).
            labels_so_far: the dataset's size now (the reviewers' round-0 discard floor reads it).
        """
        work = TeamWork()
        for pass_index in range(max_passes):
            annotated = self.annotate_all(round_index, work, annotation_limit if pass_index == 0 else None)
            if annotated:
                wait()
            reviewed = self.review_all(round_index, work, labels_so_far)
            work.passes = pass_index + 1
            log.info("round %d pass %d: %d annotations, %d reviews", round_index, pass_index + 1, annotated, reviewed)
            if not annotated and not reviewed:
                break
        return work
