"""Admin: rounds, jobs, statistics, imports, review-queue builds."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import Field

from backend.models.enums import JobKind, JobState, RoundState
from backend.schemas.base import Id, Public, Strict


class RoundCreate(Strict):
    mvnet_version: str | None = Field(default=None, max_length=100)
    handsegnet_version: str | None = Field(default=None, max_length=100)
    note: str = Field(default="", max_length=2000)


class RoundPublic(Public):
    id: int
    index: int
    state: RoundState
    mvnet_version: str | None
    handsegnet_version: str | None
    note: str
    counts: dict[str, Any]
    created_at: datetime
    finished_at: datetime | None
    failure: str | None = Field(default=None, description="Why the round's job failed (state 'failed'); the "
                                "round before it was opened again.")


class RoundLaunched(Public):
    round: RoundPublic
    job_id: int


class JobPublic(Public):
    id: int
    kind: JobKind
    state: JobState
    progress: float
    message: str
    error: str | None
    sample_id: int | None
    round_id: int | None
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None = Field(default=None, description="When the current attempt started; null: "
                                        "no worker has started it.")
    finished_at: datetime | None
    result: dict[str, Any] | None = None  # what the worker recorded, e.g. a round's counts and model versions
    attempts: int = 0  # how many times a worker started it (more than 1: redelivered or taken over)
    worker: str | None = None


class StreamCounts(Public):
    heuristic: int = 0
    manual: int = 0
    annotated: int = 0


class DecisionCounts(Public):
    """People's decisions in a round, by kind (the heuristic's accepts are its D^h)."""

    accept: int = 0
    discard: int = 0  # back to the pool for the next round's fit
    annotate: int = 0  # sent to the annotators
    reject: int = 0


class RoundStats(Public):
    round_id: int
    index: int
    state: RoundState
    added: StreamCounts
    added_total: int
    dataset_size_after: int  # |D_{i+1}| = |D_i| + added
    decisions: DecisionCounts = Field(default_factory=DecisionCounts,
                                      description="Reviewers' (and auditors') decisions made in the round, by kind.")


class Statistics(Public):
    samples_by_state: dict[str, int]
    rounds: list[RoundStats]
    submissions: int
    clicks: int = Field(description="Points placed by hand (not the not-annotated rows, nor accepted proposals).")


class ImportRequest(Strict):
    path: str = Field(min_length=1, max_length=4096, description="Capture directory on the server.")
    project: str | None = Field(default=None, max_length=200)
    queue_for_annotation: bool = True
    preannotate: bool | None = Field(
        default=None, description="Import the samples unlabeled and queue their pre-annotation by the pretrained "
        "detector (round 0 without clicks): true refuses the import (503) where the detector cannot run; "
        "left out, the server's HANDLOOP_PREANNOTATE_ON_IMPORT decides (and a missing detector only skips it).")


class ImportPublic(Public):
    project_id: int
    project: str
    cameras: int
    sequences: int
    samples: int
    views: int
    masks: int
    preannotation: str | None = Field(default=None, description="With pre-annotation: the job queued, or why it "
                                      "did not run (the import is then as without it).")
    preannotation_job_id: int | None = None


class ReviewQueueBuilt(Public):
    queued: list[int]


class PreannotateRequest(Strict):
    """Round 0 without clicks: detector -> triangulation -> fit on a project's unlabeled samples."""

    project_id: Id
    sample_ids: list[Id] | None = Field(default=None, min_length=1, max_length=1_000_000,
                                         description="Unlabeled samples of the project; default all of them.")
    rest: Literal["annotate", "keep"] = Field(
        default="keep", description="Samples the reviewers' queue does not take, and those with no detector "
        "fit: left as they are for the next round (the paper's treatment), or to the annotators now (with the "
        "detector's keypoints as proposals). Fits the reviewers send back go to the annotators either way.")
    handedness: Literal["right", "left"] | None = Field(
        default=None, description="Which hand the detector looks for, for every chosen sample; default each "
        "sample's sequence's side (recorded at import).")


class PreannotateLaunched(Public):
    job_id: int
    project_id: int
    samples: int


class PreannotationProject(Public):
    project_id: int
    name: str
    samples: int
    unlabeled: int
    running_job_id: int | None = Field(description="Its pre-annotation job still queued or running, if any.")


class PreannotationOverview(Public):
    available: bool
    reason: str | None = Field(description="Why the detector cannot run (None when it can).")
    projects: list[PreannotationProject]
