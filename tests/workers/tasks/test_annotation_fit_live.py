"""The first milestone, end to end through real processes: an annotator submits clicks, the fit job runs on
the embedded Celery worker (filesystem broker, no server), the sample reaches review with a fit."""

from __future__ import annotations

import time

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import undefer

from tests.support.annotate import clicks_body, ground_truth_of


def _wait_state(stack, sample_id: int, states: set[str], timeout_s: float = 240.0) -> str:
    from backend.models.capture import Sample

    factory = stack.session_factory()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with factory() as session:
            state = session.execute(select(Sample.state).where(Sample.id == sample_id)).scalar_one()
        if state in states:
            return state
        time.sleep(0.5)
    raise TimeoutError(f"sample {sample_id} still {state}; worker log:\n{stack.stack.worker_log.read_text()[-4000:]}")


def test_submitted_clicks_are_fitted_by_the_embedded_worker(live_stack):
    stack = live_stack(frames=2)
    with stack.client("annotator") as http:
        task = http.post("/api/annotate/next").json()
        body = clicks_body(stack, task)
        response = http.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body)
        assert response.status_code == 201, response.text
    job_id = response.json()["fit_job_id"]
    job = stack.wait_for_job(job_id)
    assert job["state"] == "succeeded", job
    assert _wait_state(stack, task["sample_id"], {"in_review"}) == "in_review"

    from backend.models.fits import Fit
    from backend.models.jobs import Job

    with stack.session_factory()() as session:
        fits = session.execute(select(Fit).options(undefer(Fit.vertices_f32))
                               .where(Fit.sample_id == task["sample_id"])).scalars().all()
        row = session.get(Job, job_id)
    assert len(fits) == 1 and fits[0].job_id == job_id and row.attempts == 1
    assert fits[0].inputs["source"] == "annotation" and fits[0].inputs["submission_ids"]
    assert len(fits[0].diagnostics["model_mask_keys"]) == len(task["views"])
    # A fit from exact clicks on the sparse keypoints lands near the truth (tiny schedule: a loose bound).
    truth = ground_truth_of(stack, task)
    error_mm = 1000 * np.linalg.norm(np.asarray(fits[0].keypoints_m) - truth.keypoints_3d, axis=1).mean()
    assert error_mm < 40, error_mm
    # The worker's mesh is stored with the fit (the API shows it without posing the hand again).
    vertices = np.frombuffer(fits[0].vertices_f32, "<f4").reshape(-1, 3)
    assert vertices.shape == truth.vertices.shape
    assert 1000 * np.linalg.norm(vertices - truth.vertices, axis=1).mean() < 40
