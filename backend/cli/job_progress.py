"""A job's progress in a terminal: the admin page's live bar (its row's state, progress and message) for
`handloop import --wait` and `handloop demo`, which follow the pre-annotation they queued."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TextIO

from sqlalchemy.orm import Session
from tqdm import tqdm

from backend.models.enums import JobState
from backend.services.jobs import jobs

WAITING = "waiting for a worker (`handloop worker`)"


@dataclass(frozen=True)
class JobEnd:
    """How a followed job ended: its state ("succeeded", "failed", "cancelled"), error and result."""

    job_id: int
    state: str
    error: str | None
    result: dict[str, Any] | None


def _snapshot(session_factory: Callable[[], Session], job_id: int) -> tuple[str, float, str, str | None, Any]:
    with session_factory() as session:
        job = jobs.get(session, job_id)
        return str(job.state), float(job.progress or 0.0), job.message or "", job.error, job.result


def _sleep(seconds: float) -> bool:
    time.sleep(seconds)
    return False


def follow_job(session_factory: Callable[[], Session], job_id: int, *, label: str, poll_s: float = 1.0,
               wait: Callable[[float], bool] | None = None, out: TextIO | None = None) -> JobEnd | None:
    """Draw the job's progress (0-100 %) and message until it is final; returns how it ended.

    Reads the job's row every `poll_s` seconds (a worker writes it), as the page's server-sent events do;
    `wait(poll_s)` waits between reads and returns True to stop following (then None is returned: the job
    goes on; default: sleep). A job still queued shows that it waits for a worker."""
    wait = wait or _sleep
    with tqdm(total=100, desc=label, unit="%", file=out or sys.stderr,
              bar_format="{desc}: {percentage:3.0f}%|{bar}|{postfix}") as bar:
        while True:
            state, progress, message, error, result = _snapshot(session_factory, job_id)
            bar.update(round(100 * progress) - bar.n)
            if JobState(state) in jobs.FINAL_STATES:
                bar.set_postfix_str(state)
                return JobEnd(job_id, state, error, result)
            bar.set_postfix_str(WAITING if state == JobState.queued else message)
            if wait(poll_s):
                return None


def preannotation_summary(result: dict[str, Any]) -> str:
    """One line of a finished preannotate job's result (workers.tasks.preannotate)."""
    keys = ("samples", "detected", "fitted", "no_detection", "fit_failed", "to_review", "fitted_to_annotators",
            "unlabeled_to_annotators")
    return ", ".join(f"{result[k]} {k.replace('_', ' ')}" for k in keys if k in result)
