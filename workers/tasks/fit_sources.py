"""The fit input of a fit job, by the job's source: the annotators' clicks and masks, a prediction of the
networks, or the pretrained detector's detection (pre-annotation)."""

from __future__ import annotations

import dataclasses

from sqlalchemy.orm import Session

from backend.models.jobs import Job
from workers.tasks.context import WorkerContext
from workers.tasks.detection_inputs import fit_input_from_detection
from workers.tasks.inputs import (
    FitInput,
    InputError,
    SampleFrame,
    from_annotation,
    from_prediction,
    load_frames,
    rig_of,
)


def fit_input(ctx: WorkerContext, session: Session, job: Job, frames: dict[int, SampleFrame] | None = None
              ) -> FitInput:
    """The fit input of a fit job, for the hand of the sample's sequence (`side`). `frames`: frames already
    loaded for several jobs (load_frames), to save the queries."""
    if job.sample_id is None:
        raise InputError(f"fit job {job.id} names no sample")
    if frames is None or job.sample_id not in frames:
        frames = load_frames(ctx, session, [job.sample_id])
    if job.sample_id not in frames:
        raise InputError(f"sample {job.sample_id} of fit job {job.id} no longer exists")
    frame = frames[job.sample_id]
    rig = rig_of(ctx, session, frame.project_id)
    source = str((job.payload or {}).get("source", "annotation"))
    if source == "prediction":
        fi = from_prediction(ctx, session, job, frame, rig)
    elif source == "detector":
        fi = fit_input_from_detection(ctx, session, job, frame, rig)
    else:
        fi = from_annotation(ctx, session, job, frame, rig)
    return dataclasses.replace(fi, side=frame.side)
