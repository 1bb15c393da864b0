"""The calibration check of an imported project from its annotators' clicks (workers/rigs/check.py):
read-only, for the admin page (GET /api/admin/projects/{project_id}/calibration-check)."""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.models.capture import CameraCalibration, Project, Sample, Sequence, View
from backend.models.enums import Visibility
from backend.models.labels import Click, Submission
from backend.services.errors import ConflictError, NotFoundError
from workers.geometry.camera import Camera

MAX_SUBMISSIONS = 200  # the latest ones: enough for a stable median, bounded work per request


def calibration_check(session: Session, project_id: int, max_submissions: int = MAX_SUBMISSIONS) -> dict[str, Any]:
    """The check's report (CheckReport.to_dict) from the visible clicks of the latest submissions."""

    if session.get(Project, project_id) is None:
        raise NotFoundError(f"no project {project_id}")
    rows = session.execute(select(CameraCalibration).where(CameraCalibration.project_id == project_id)
                           .order_by(CameraCalibration.id)).scalars().all()
    cameras = [Camera(r.name, r.width, r.height, np.asarray(r.K), np.asarray(r.dist), np.asarray(r.R),
                      np.asarray(r.t)) for r in rows]
    index = {r.id: c for c, r in enumerate(rows)}
    latest = select(Submission.id).join(Sample, Sample.id == Submission.sample_id) \
        .join(Sequence, Sequence.id == Sample.sequence_id).where(Sequence.project_id == project_id) \
        .order_by(Submission.id.desc()).limit(max_submissions)
    clicks = session.execute(
        select(Click.submission_id, View.camera_id, Click.keypoint, Click.x_px, Click.y_px)
        .join(View, View.id == Click.view_id)
        .where(Click.submission_id.in_(latest.scalar_subquery()), Click.visibility == Visibility.visible.value,
               Click.x_px.is_not(None), Click.y_px.is_not(None),
               # accepted proposals are the proposals' own geometry, not a person's view of the hand
               Click.from_proposal.is_(False))).all()
    frames: dict[int, np.ndarray] = {}
    for submission_id, camera_id, keypoint, x, y in clicks:
        kp = frames.setdefault(submission_id, np.full((len(cameras), 21, 2), np.nan))
        kp[index[camera_id], keypoint] = (x, y)
    keypoints = [frames[s] for s in sorted(frames)]
    visible = [np.isfinite(kp).all(axis=2) for kp in keypoints]
    notes = [] if keypoints else ["no visible clicks yet: the check needs annotated samples"]
    # deferred: the check's pose fits load cv2 and torch (undistortion), kept out of the API's start-up
    from workers.rigs.check import CheckError, check_keypoints

    try:
        report = check_keypoints(cameras, keypoints, visible, source="clicks", notes=notes)
    except CheckError as exc:  # the project's rig or clicks cannot be checked (yet): its state, not the request
        raise ConflictError(str(exc)) from None
    return report.to_dict()
