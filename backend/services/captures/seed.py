"""Synthetic rows without images, for benchmarks and tests: a project with a rig of cameras and samples
in a given state. (Real data comes in through backend.services.captures.importer.)"""

from __future__ import annotations

from sqlalchemy import insert
from sqlalchemy.orm import Session

from backend.models.capture import CameraCalibration, Project, Sample, Sequence, Subject, View
from backend.models.enums import SampleState, Split

IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


def seed_samples(session: Session, *, project: str = "seeded", sequences: int = 1, frames: int = 10,
                 cameras: int = 8, width: int = 96, height: int = 96, fps: float = 30.0,
                 state: SampleState = SampleState.needs_annotation) -> list[int]:
    """Create a project with `sequences` x `frames` samples of `cameras` views each; returns sample ids
    in (sequence, frame) order. Image keys point at nothing: only the rows exist."""
    proj = Project(name=project, description="seeded rows, no images")
    session.add(proj)
    session.flush()
    cams = [CameraCalibration(project_id=proj.id, name=f"cam{c}", width=width, height=height,
                              K=[[100.0, 0.0, width / 2], [0.0, 100.0, height / 2], [0.0, 0.0, 1.0]],
                              dist=[0.0] * 5, R=IDENTITY, t=[0.0, 0.0, 0.5]) for c in range(cameras)]
    subject = Subject(project_id=proj.id, external_id="s0")
    session.add_all([*cams, subject])
    session.flush()
    ids: list[int] = []
    for s in range(sequences):
        seq = Sequence(project_id=proj.id, subject_id=subject.id, external_id=f"seq{s:03d}", split=Split.train,
                       green_screen=True, fps=fps)
        session.add(seq)
        session.flush()
        rows = session.execute(insert(Sample).returning(Sample.id, sort_by_parameter_order=True), [
            {"sequence_id": seq.id, "frame_index": f, "time_s": f / fps, "split": Split.train.value,
             "green_screen": True, "state": SampleState(state).value} for f in range(frames)
        ]).scalars().all()
        session.execute(insert(View), [
            {"sample_id": sid, "camera_id": cam.id, "image_key": f"seeded/{sid}/{cam.name}.png", "width": width,
             "height": height} for sid in rows for cam in cams
        ])
        ids.extend(rows)
    return ids
