"""Submissions made from a synthetic capture's ground truth: what a careful annotator would click."""

from __future__ import annotations

import uuid
from typing import Any

import numpy as np
from sqlalchemy import select

from tests.support.live_stack import LiveStack


def ground_truth_of(stack: LiveStack, task: dict[str, Any]) -> Any:
    """The task's frame's ground truth (workers.capture.GroundTruth), read from the stack's capture."""
    from backend.models.capture import Sequence
    from workers.capture import load_ground_truth, read_capture

    factory = stack.session_factory()
    with factory() as session:
        external = session.execute(select(Sequence.external_id).where(Sequence.id == task["sequence_id"])).scalar_one()
    capture = read_capture(stack.capture_dir, check_images=False)
    frame = capture.sequence(external).frames[task["frame_index"]]
    return load_ground_truth(frame)


def clicks_body(stack: LiveStack, task: dict[str, Any], *, noise_px: float = 0.0, seed: int = 0,
                submission_id: str | None = None) -> dict[str, Any]:
    """Clicks on the task's keypoints at their true projections (visible ones), optionally with noise."""
    gt = ground_truth_of(stack, task)
    rng = np.random.default_rng(seed)
    clicks = []
    for view in task["views"]:
        c = list(gt.camera_names).index(view["camera"])
        for k in task["keypoints_to_click"]:
            x, y = gt.keypoints_2d[c, k] + rng.normal(0, noise_px, 2) if noise_px else gt.keypoints_2d[c, k]
            inside = -0.5 <= x <= view["width"] - 0.5 and -0.5 <= y <= view["height"] - 0.5
            if gt.visibility[c, k] and inside:
                clicks.append({"view_id": view["id"], "keypoint": k, "x": float(x), "y": float(y),
                               "visibility": "visible"})
            else:
                clicks.append({"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"})
    return {"submission_id": submission_id or uuid.uuid4().hex, "lease_token": task["lease_token"],
            "time_spent_s": 12.0, "clicks": clicks}
