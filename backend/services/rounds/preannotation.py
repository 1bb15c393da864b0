"""Launching pre-annotation (issue 15, round 0 without clicks): one 'preannotate' job per project, which a
worker runs (workers.tasks.preannotate): detector -> triangulation -> fit on the chosen unlabeled samples,
then the reviewers' queue by the paper's policy.

Everything is checked before anything is written: the detector's model files (where they are missing the
action is refused with the detector's own sentence, and the paper-only path is as before), the project,
its calibration (two views at least), the samples (unlabeled ones of this project), and that no other
pre-annotation of the project is under way.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal

from sqlalchemy import case, func, select
from sqlalchemy.orm import Session

from backend.models.capture import CameraCalibration, Project, Sample
from backend.models.capture import Sequence as CaptureSequence
from backend.models.enums import JobKind, JobState, SampleState
from backend.models.jobs import Job
from backend.schemas.admin import ImportPublic
from backend.services import audit
from backend.services.captures.storage import Storage
from backend.services.errors import ConflictError, InvalidInputError, NotFoundError, ServiceUnavailableError
from backend.services.jobs import jobs
from backend.services.labeling.annotation_set import queue_for_annotation as queue_samples
from workers.detector.model_files import detector_status, loaded_detector_status

Rest = Literal["annotate", "keep"]
MAX_LISTED = 20  # ids named in an error message
RESTS = ("annotate", "keep")  # what happens to samples the reviewers' queue does not take
DEFAULT_REST: Rest = "keep"  # the paper leaves every round's unpicked samples for the next round
MIN_VIEWS = 2  # one view cannot place a hand in 3D


def detector_problem() -> str | None:
    """None when the pretrained detector can run on this install (the workers share it), else why not.

    The runtime is imported: installed but unable to load (its native library) is a problem. Asked by the
    pre-annotation job in the worker, by a launch (refused rather than queued to fail) and by an import (its
    samples' queue depends on the answer); the first import of the runtime takes seconds."""
    return loaded_detector_status()


def quick_detector_problem() -> str | None:
    """As `detector_problem` from the model files' checksums and the runtime's presence on the import path:
    nothing heavy is imported (not the detector's pipeline, torch or the runtime), so the admin page's status
    answers in milliseconds. A runtime that is installed but cannot load passes it (a launch then says so)."""
    return detector_status()


def project_problem(session: Session, project_id: int) -> str | None:
    """None when the project's calibration can carry a pre-annotation, else what is wrong with it."""
    cameras = session.execute(select(func.count()).select_from(CameraCalibration)
                              .where(CameraCalibration.project_id == project_id)).scalar_one()
    if cameras == 0:
        return f"project {project_id} has no camera calibration"
    if cameras < MIN_VIEWS:
        return (f"project {project_id} has {cameras} calibrated view; pre-annotation needs at least "
                f"{MIN_VIEWS} to place a hand in 3D")
    return None


def _listed(ids: Sequence[object]) -> str:
    return ", ".join(str(i) for i in ids[:MAX_LISTED]) + (" ..." if len(ids) > MAX_LISTED else "")


def _samples_of(session: Session, project_id: int, sample_ids: Sequence[int] | None) -> list[int]:
    """The project's unlabeled samples (all, or exactly `sample_ids`: all or nothing)."""
    query = (select(Sample.id, Sample.state).join(CaptureSequence, CaptureSequence.id == Sample.sequence_id)
             .where(CaptureSequence.project_id == project_id).order_by(Sample.id))
    states = dict(session.execute(query).all())
    if sample_ids is None:
        unlabeled = [s for s, state in states.items() if state == SampleState.unlabeled]
        if not unlabeled:
            raise ConflictError(f"project {project_id} has no unlabeled samples to pre-annotate")
        return unlabeled
    wanted = list(dict.fromkeys(int(i) for i in sample_ids))
    if not wanted:
        raise InvalidInputError("sample_ids is empty; leave it out to pre-annotate every unlabeled sample")
    if foreign := [i for i in wanted if i not in states]:
        raise NotFoundError(f"samples not in project {project_id}: {_listed(foreign)}")
    if busy := [f"{i} is '{states[i]}'" for i in wanted if states[i] != SampleState.unlabeled]:
        raise ConflictError(f"only unlabeled samples can be pre-annotated: {_listed(busy)}")
    return wanted


def running_job(session: Session, project_id: int) -> Job | None:
    """The project's pre-annotation job still queued or running, if any."""
    for job in session.execute(select(Job).where(Job.kind == JobKind.preannotate,
                                                 Job.state.in_([JobState.queued, JobState.running]))).scalars():
        if (job.payload or {}).get("project_id") == project_id:
            return job
    return None


def overview(session: Session) -> dict[str, object]:
    """Whether the detector can run, and per project its samples, how many are unlabeled, its running job."""
    problem = quick_detector_problem()
    rows = session.execute(
        select(Project.id, Project.name, func.count(Sample.id),
               func.coalesce(func.sum(case((Sample.state == SampleState.unlabeled, 1), else_=0)), 0))
        .outerjoin(CaptureSequence, CaptureSequence.project_id == Project.id)
        .outerjoin(Sample, Sample.sequence_id == CaptureSequence.id)
        .group_by(Project.id, Project.name).order_by(Project.id)).all()
    projects = []
    for project_id, name, samples, unlabeled in rows:
        job = running_job(session, project_id)
        projects.append({"project_id": project_id, "name": name, "samples": int(samples), "unlabeled": int(unlabeled),
                         "running_job_id": job.id if job is not None else None})
    return {"available": problem is None, "reason": problem, "projects": projects}


def launch(session: Session, queue: jobs.JobQueue, project_id: int, *, actor_id: int | None,
           sample_ids: Sequence[int] | None = None, rest: Rest = DEFAULT_REST,
           handedness: Literal["right", "left"] | None = None) -> Job:
    """Queue a preannotate job for the project's unlabeled samples (or the given ones).

    `rest`: what happens to samples the reviewers' queue does not take, and to those with no detector fit:
    "keep" (the default: the paper leaves every round's unpicked samples for the next round's MVNet) leaves them
    where they are (unlabeled, or fitted for the next round to refit); "annotate" hands them to the annotators
    (with the detector's keypoints as proposals where it made a fit). Fits the reviewers send back reach the
    annotators either way.
    `handedness`: the hand the detector looks for in every sample; None: each sample's sequence's side.

    Raises ServiceUnavailableError (the detector cannot run: its sentence), NotFoundError, InvalidInputError
    (no calibration, fewer than two views, bad ids), ConflictError (no unlabeled samples, samples in another
    state, a pre-annotation of the project already under way). Nothing is written when it raises.
    """
    if rest not in RESTS:
        raise InvalidInputError(f"rest must be one of {list(RESTS)}, not {rest!r}")
    problem = detector_problem()
    if problem is not None:
        raise ServiceUnavailableError(f"pre-annotation is unavailable: {problem}")
    if session.get(Project, project_id) is None:
        raise NotFoundError(f"project {project_id} not found")
    problem = project_problem(session, project_id)
    if problem is not None:
        raise InvalidInputError(f"cannot pre-annotate: {problem}")
    if (busy := running_job(session, project_id)) is not None:
        raise ConflictError(f"project {project_id} is already being pre-annotated (job {busy.id}, {busy.state})")
    chosen = _samples_of(session, project_id, sample_ids)
    job = jobs.create(session, queue, JobKind.preannotate, actor_id=actor_id,
                      payload={"project_id": project_id, "sample_ids": chosen, "rest": rest,
                               "handedness": handedness})
    audit.record(session, actor_id, "preannotation.launch", "project", project_id, job_id=job.id,
                 samples=len(chosen), rest=rest)
    return job


def import_capture(session: Session, storage: Storage, queue: jobs.JobQueue, path: Path, *, enabled: bool,
                   project_name: str | None, queue_for_annotation: bool, actor_id: int | None,
                   required: bool = False, progress: Callable[[int, int], None] | None = None) -> ImportPublic:
    """The import, followed (when `enabled`) by a pre-annotation of every sample: round 0 in one action.

    The samples are imported 'unlabeled' and the pre-annotation routes them: reviewers get what the policy picks,
    the rest go to the annotators when the import asked for that (`queue_for_annotation`). Where the detector
    or the capture cannot carry it, the import is exactly as without it, and the answer says why; with
    `required` (the caller asked for it by name) a detector that cannot run refuses the import instead, before
    anything is read or written (ServiceUnavailableError with the detector's sentence).
    """
    from backend.services.captures import importer  # deferred: its capture reader pulls in cv2 and PIL

    problem = detector_problem() if enabled else None
    if required and problem is not None:
        raise ServiceUnavailableError(f"pre-annotation is unavailable: {problem}; nothing was imported: import "
                                      "without pre-annotation, or install the detector (docs/detector.md)")
    run = enabled and problem is None
    result = importer.import_capture(session, storage, path, project_name=project_name,
                                     queue_for_annotation=queue_for_annotation and not run, actor_id=actor_id,
                                     progress=progress)
    if not run:
        return result.model_copy(update={"preannotation": f"not run: {problem}" if enabled else None})
    try:
        with session.begin_nested():
            job = launch(session, queue, result.project_id, actor_id=actor_id,
                         rest="annotate" if queue_for_annotation else "keep")
    except (InvalidInputError, ConflictError, NotFoundError, ServiceUnavailableError) as exc:
        if queue_for_annotation and result.samples:
            ids = session.execute(select(Sample.id).join(CaptureSequence, CaptureSequence.id == Sample.sequence_id)
                                  .where(CaptureSequence.project_id == result.project_id)).scalars().all()
            queue_samples(session, list(ids), actor_id)
        return result.model_copy(update={"preannotation": f"not run: {exc.message}"})
    return result.model_copy(update={"preannotation": f"job {job.id} queued", "preannotation_job_id": job.id})
