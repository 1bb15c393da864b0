"""Left hands (issue 18): a synthetic left-hand capture (`SynthConfig(side="left")`, ground truth from the
left model) imports as a left-hand sequence, its fit job loads the left model, and the fit's keypoints
project onto the synthetic ones; the same clicks fitted with the right model land clearly worse."""

from __future__ import annotations

import dataclasses
import uuid

import numpy as np
import pytest
from sqlalchemy import select

from backend.models.capture import Sequence
from backend.models.fits import Fit
from backend.models.jobs import Job
from tests.support.annotator_world import annotator_world
from tests.support.live_stack import tiny_capture
from workers.capture import load_ground_truth, read_capture
from workers.geometry.projection import project_points
from workers.tasks.fit_sources import fit_input
from workers.tasks.fits import engine_for, fit_config, run_fit_jobs


@pytest.fixture
def left_world(tmp_path, capture_cache):
    capture = tiny_capture(capture_cache, frames=2, side="left")
    with annotator_world(tmp_path / "data", capture) as (_settings, client, _queue, ctx):
        yield capture, client, ctx


def _exact_clicks(capture_dir, task: dict) -> tuple[dict, object]:
    capture = read_capture(capture_dir, check_images=False)
    truth = load_ground_truth(capture.sequences[0].frames[task["frame_index"]])
    clicks = []
    for view in task["views"]:
        c = list(truth.camera_names).index(view["camera"])
        for k in task["keypoints_to_click"]:
            x, y = (float(v) for v in truth.keypoints_2d[c, k])
            ok = truth.visibility[c, k] and -0.5 <= x <= view["width"] - 0.5 and -0.5 <= y <= view["height"] - 0.5
            clicks.append({"view_id": view["id"], "keypoint": k, "x": x, "y": y, "visibility": "visible"} if ok
                          else {"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"})
    body = {"submission_id": uuid.uuid4().hex, "lease_token": task["lease_token"], "time_spent_s": 3.0,
            "clicks": clicks}
    return body, truth


def _reprojection_px(capture_dir, keypoints_m: np.ndarray, truth) -> float:
    """Mean distance (pixels) between the keypoints (21, 3) projected into every view and the synthetic
    2D keypoints, over the keypoints visible there."""
    cameras = {c.name: c for c in read_capture(capture_dir, check_images=False).cameras}
    projected, _ = project_points(np.asarray(keypoints_m, np.float64), [cameras[str(n)] for n in truth.camera_names])
    gaps = []
    for c, pixels in enumerate(projected):
        visible = np.asarray(truth.visibility[c], bool)
        gaps.append(np.linalg.norm(pixels[visible] - np.asarray(truth.keypoints_2d[c])[visible], axis=1))
    return float(np.concatenate(gaps).mean())


def test_a_left_hand_capture_imports_as_left_and_fits_with_the_left_model(left_world):
    capture_dir, client, ctx = left_world
    assert read_capture(capture_dir, check_images=False).hand_model.side == "left"
    with ctx.session_factory() as session:
        assert session.execute(select(Sequence.side)).scalars().all() == ["left"]
    task = client.post("/api/annotate/next").json()
    assert task["side"] == "left"  # what the annotate page shows
    body, truth = _exact_clicks(capture_dir, task)
    response = client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body)
    assert response.status_code == 201, response.text
    job_id = response.json()["fit_job_id"]

    # The same inputs fitted with the right model, for comparison (loading inputs claims nothing).
    with ctx.session_factory() as session:
        fi = fit_input(ctx, session, session.get(Job, job_id))
    assert fi.side == "left"
    config = fit_config(ctx, fi.source)
    right = engine_for(ctx, dataclasses.replace(fi, side="right"), config).fit([fi.observations])[0]
    assert engine_for(ctx, fi, config).arrays.side == "left"

    summary = run_fit_jobs(ctx, [job_id])
    assert len(summary.fitted) == 1, summary.to_dict()
    with ctx.session_factory() as session:
        fit = session.get(Fit, summary.fitted[0])
        keypoints = np.asarray(fit.keypoints_m)
        assert fit.diagnostics["hand_side"] == "left"
    left_px = _reprojection_px(capture_dir, keypoints, truth)
    right_px = _reprojection_px(capture_dir, right.keypoints, truth)
    left_mm = 1000 * np.linalg.norm(keypoints - truth.keypoints_3d, axis=1).mean()
    right_mm = 1000 * np.linalg.norm(right.keypoints - truth.keypoints_3d, axis=1).mean()
    # Seen: left model 0.69 px / 5.0 mm, right model 1.93 px / 13.9 mm (built-in hand, the tests' iterations).
    assert left_px < 3.0, left_px
    assert right_px > 2 * left_px and right_mm > 2 * left_mm, (left_px, right_px, left_mm, right_mm)
