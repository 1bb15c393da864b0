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


def queue_for_annotation(stack: LiveStack, count: int) -> list[int]:
    """Move the first `count` unlabeled samples to the annotators' queue (round 0's D_0 candidates)."""
    from backend.models.capture import Sample
    from backend.models.enums import SampleState
    from backend.services.captures.state_machine import transition

    with stack.session_factory().begin() as session:
        samples = session.execute(select(Sample).where(Sample.state == SampleState.unlabeled).order_by(Sample.id)
                                  .limit(count)).scalars().all()
        for sample in samples:
            transition(session, sample, SampleState.needs_annotation, None, reason="test: D_0")
        return [s.id for s in samples]


def wait_until(predicate: Any, timeout_s: float, what: str, stack: LiveStack | None = None) -> Any:
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.5)
    log = stack.stack.worker_log.read_text()[-5000:] if stack else ""
    raise TimeoutError(f"{what} not reached within {timeout_s} s\n{log}")


def annotate_and_accept(stack: LiveStack, count: int, *, noise_px: float = 0.0, timeout_s: float = 300.0) -> list[int]:
    """Round 0 through the API: annotate `count` queued samples from ground truth, wait for their fits, and
    accept each as a reviewer. Returns the accepted sample ids."""
    submitted = []
    with stack.client("annotator") as http:
        for i in range(count):
            task = http.post("/api/annotate/next")
            assert task.status_code == 200, task.text
            body = clicks_body(stack, task.json(), noise_px=noise_px, seed=i)
            response = http.post(f"/api/annotate/samples/{task.json()['sample_id']}/submissions", json=body)
            assert response.status_code == 201, response.text
            submitted.append(response.json()["fit_job_id"])
    for job_id in submitted:
        job = stack.wait_for_job(job_id, timeout_s)
        assert job["state"] == "succeeded", job
    accepted = []
    with stack.client("reviewer") as http:
        for _ in range(count):
            task = http.post("/api/review/next")
            assert task.status_code == 200, task.text
            sample_id = task.json()["sample_id"]
            decision = http.post(f"/api/review/samples/{sample_id}/decision",
                                 json={"decision": "accept", "lease_token": task.json()["lease_token"]})
            assert decision.status_code == 201, decision.text
            accepted.append(sample_id)
    return accepted
