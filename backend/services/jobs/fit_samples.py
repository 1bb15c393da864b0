"""What the end of a fit job means for its sample: out of 'fitting', however the job ended.

Below both the job services (jobs.py, which gives up on or cancels a job) and the fit records
(records.py, which records a failed fit), so that neither has to import the other.
"""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.models.capture import Sample
from backend.models.enums import JobKind, JobState, SampleState
from backend.models.jobs import Job
from backend.services.captures.state_machine import transition
from backend.services.leases import annotation_flags, queues


def release_failed_fit(session: Session, sample: Sample, error: str) -> None:
    """A fit that could not be made sends its (locked) sample back to the annotators."""
    if sample.state == SampleState.fitting:
        transition(session, sample, SampleState.needs_annotation, None, reason=f"fit failed: {error}")
        # Shown to the submission's author, and the queue gives the sample to someone else (not back in a loop).
        annotation_flags.record_fit_failure(session, sample, error)


def release_cancelled_fit(session: Session, sample_id: int, job_id: int) -> None:
    """A cancelled fit job lets its sample out of 'fitting': back to 'fitted' when it has an earlier fit,
    else to the annotators (the only other way out of 'fitting'). Unless another fit of it is pending."""
    sample = queues.load_locked(session, sample_id)
    if sample.state != SampleState.fitting:
        return
    pending = session.execute(
        select(func.count()).select_from(Job).where(Job.sample_id == sample_id, Job.kind == JobKind.fit,
                                                    Job.id != job_id,
                                                    Job.state.in_([JobState.queued, JobState.running]))
    ).scalar_one()
    if pending:
        return
    target = SampleState.fitted if sample.current_fit_id is not None else SampleState.needs_annotation
    transition(session, sample, target, None, reason=f"fit job {job_id} cancelled")
