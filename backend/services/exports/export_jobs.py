"""The FreiHAND export as a job (the admin page's "Export in FreiHAND's layout"): the API queues an 'export'
job, a worker writes the layout (workers.tasks.export, the same writer as `handloop export --format freihand`)
and packs it into one zip archive in storage, reporting its progress on the job row; the admin downloads the
archive once the job succeeded. The API process loads neither torch nor the hand model."""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from backend.models.enums import JobKind, JobState
from backend.models.jobs import Job
from backend.services import audit
from backend.services.errors import ConflictError, InvalidInputError, NotFoundError
from backend.services.exports import export
from backend.services.jobs import jobs

MESH_CHOICES = ("ply", "obj", "ply,obj", "none")


def archive_key(job_id: int) -> str:
    """Where the job's zip archive lives in storage."""
    return f"exports/freihand/job-{job_id}.zip"


def queue_freihand_export(session: Session, queue: jobs.JobQueue, actor_id: int | None, *,
                          up_to_round: int | None = None, project: str | None = None, composites: int = 0,
                          meshes: str = "ply") -> Job:
    """Queue an export job after checking what it would export: 404 for an unknown round or project, 409 when
    no sample is accepted yet (nothing is queued then)."""
    if meshes not in MESH_CHOICES:
        raise InvalidInputError(f"meshes must be one of {', '.join(MESH_CHOICES)}, not {meshes!r}")
    if not 0 <= composites <= 8:
        raise InvalidInputError(f"composites must be in 0..8, not {composites}")
    records = export.export_records(session, up_to_round, project)
    if not records:
        where = f" in project {project!r}" if project else ""
        raise ConflictError(f"nothing to export yet: no accepted sample{where}"
                            + (f" up to round {up_to_round}" if up_to_round is not None else ""))
    payload: dict[str, Any] = {"format": "freihand", "up_to_round": up_to_round, "project": project,
                               "composites": composites, "meshes": meshes, "samples": len(records)}
    job = jobs.create(session, queue, JobKind.export, actor_id=actor_id, payload=payload)
    audit.record(session, actor_id, "export.freihand", "job", job.id, samples=len(records))
    return job


def finished_archive(session: Session, job_id: int) -> str:
    """The storage key of a succeeded export job's archive; 404 for no such export job, 409 while it runs or
    when it failed (with its error)."""
    job = jobs.get(session, job_id)
    if job.kind != JobKind.export:
        raise NotFoundError(f"job {job_id} is a {job.kind} job, not an export")
    state = JobState(job.state)
    if state is not JobState.succeeded:
        why = f": {job.error}" if job.error else ""
        raise ConflictError(f"export job {job_id} is {state.value}{why}; its archive exists once it has succeeded")
    return archive_key(job_id)
