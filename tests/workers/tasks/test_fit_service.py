"""The fit job service without a broker: a batch with one unfittable sample fits the others and records
that one as a failure; a redelivered job records nothing twice; a cancelled fit releases its sample."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import func, select

from backend.models.capture import Sample
from backend.models.enums import JobState, SampleState
from backend.models.fits import Fit
from backend.models.jobs import Job
from backend.models.labels import Click
from backend.services.jobs import jobs
from tests.support.annotator_world import annotator_world
from tests.support.live_stack import tiny_capture
from workers.tasks.fits import run_fit_jobs

CAPTURE: list = []  # the tiny capture of this session (set by `world`)


@pytest.fixture
def world(tmp_path, capture_cache):
    capture = tiny_capture(capture_cache, frames=3)
    CAPTURE[:] = [capture]
    with annotator_world(tmp_path / "data", capture) as world:
        yield world


def _submit(settings, client, *, views: int | None = None, accepted_views: int = 0) -> int:
    """Clicks from the truth; in the first `accepted_views` views marked as accepted from a proposal."""
    task = client.post("/api/annotate/next").json()
    body = _clicks(task)
    accepted = {v["id"] for v in task["views"][:accepted_views]}
    for click in body["clicks"]:
        click["from_proposal"] = click["view_id"] in accepted and click["visibility"] != "not_annotated"
    if views is not None:  # clicks in fewer views: the hand cannot be placed in 3D
        keep = {v["id"] for v in task["views"][:views]}
        body["clicks"] = [c for c in body["clicks"] if c["view_id"] in keep]
    response = client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body)
    assert response.status_code == 201, response.text
    return response.json()["fit_job_id"]


def _clicks(task: dict) -> dict:
    """Exact clicks on the visible sparse keypoints, from the capture's ground truth."""
    import uuid

    import numpy as np

    from workers.capture import load_ground_truth, read_capture

    capture = read_capture(CAPTURE[0], check_images=False)
    truth = load_ground_truth(capture.sequences[0].frames[task["frame_index"]])
    clicks = []
    for view in task["views"]:
        c = list(truth.camera_names).index(view["camera"])
        for k in task["keypoints_to_click"]:
            x, y = (float(v) for v in np.asarray(truth.keypoints_2d[c, k]))
            ok = truth.visibility[c, k] and -0.5 <= x <= view["width"] - 0.5 and -0.5 <= y <= view["height"] - 0.5
            clicks.append({"view_id": view["id"], "keypoint": k, "x": x, "y": y, "visibility": "visible"} if ok
                          else {"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"})
    return {"submission_id": uuid.uuid4().hex, "lease_token": task["lease_token"], "time_spent_s": 3.0,
            "clicks": clicks}




def test_one_unfittable_sample_does_not_sink_its_batch_and_redelivery_records_once(world):
    settings, client, _, ctx = world
    good = _submit(settings, client)
    bad = _submit(settings, client, views=1)
    summary = run_fit_jobs(ctx, [good, bad])
    assert len(summary.fitted) == 1 and list(summary.failed) == [bad], summary
    with ctx.session_factory() as session:
        assert session.get(Job, good).state == JobState.succeeded
        failed = session.get(Job, bad)
        assert failed.state == JobState.failed and "two views" in failed.error
        assert session.get(Sample, failed.sample_id).state == SampleState.needs_annotation
        assert session.get(Sample, session.get(Job, good).sample_id).state == SampleState.in_review
    again = run_fit_jobs(ctx, [good, bad])  # a redelivered task
    assert not again.fitted and sorted(again.skipped) == sorted([good, bad])
    with ctx.session_factory() as session:
        assert session.execute(select(func.count()).select_from(Fit)).scalar_one() == 1


def test_a_cancelled_fit_job_is_not_fitted_and_releases_its_sample(world):
    settings, client, queue, ctx = world
    job_id = _submit(settings, client)
    with ctx.session_factory.begin() as session:
        jobs.cancel(session, queue, job_id, None)
    with ctx.session_factory() as session:
        sample = session.get(Sample, session.get(Job, job_id).sample_id)
        assert sample.state == SampleState.needs_annotation  # no earlier fit to fall back to
    summary = run_fit_jobs(ctx, [job_id])
    assert summary.skipped == [job_id] and not summary.fitted


def test_points_accepted_from_proposals_weigh_less_than_clicks_in_the_fit_input(world):
    from workers.fitting.inputs import PROPOSAL_CLICK_WEIGHT
    from workers.tasks.fit_sources import fit_input

    settings, client, _, ctx = world
    job_id = _submit(settings, client, accepted_views=3)
    with ctx.session_factory() as session:
        job = session.get(Job, job_id)
        given = fit_input(ctx, session, job)
        weights = given.observations.click_weights  # (C, 21), views in rig order
        view_ids = list(given.view_ids)
        placed = {(r.view_id, r.keypoint): r.from_proposal for r in session.execute(
            select(Click).where(Click.sample_id == job.sample_id, Click.x_px.is_not(None))).scalars()}
    accepted = [w for (v, k), from_proposal in placed.items() if from_proposal
                for w in [weights[view_ids.index(v), k]]]
    clicked = [w for (v, k), from_proposal in placed.items() if not from_proposal
               for w in [weights[view_ids.index(v), k]]]
    assert accepted and clicked
    assert set(clicked) == {1.0} and set(accepted) == {PROPOSAL_CLICK_WEIGHT} and PROPOSAL_CLICK_WEIGHT < 1
    assert given.inputs["clicked"] == len(clicked) and given.inputs["accepted_proposals"] == len(accepted)
    assert given.inputs["clicks"] == len(placed)
    origin = given.observations.from_proposal  # (C, 21) bool, handed to the fit for its residuals
    assert {(view_ids[c], int(k)) for c, k in np.argwhere(origin)} == {key for key, f in placed.items() if f}


def test_the_recorded_fit_keeps_residuals_to_accepted_proposals_apart(world):
    from workers.tasks.fit_sources import fit_input

    settings, client, _, ctx = world
    job_id = _submit(settings, client, accepted_views=3)
    with ctx.session_factory() as session:
        view_ids = list(fit_input(ctx, session, session.get(Job, job_id)).view_ids)  # the fit's view order
    summary = run_fit_jobs(ctx, [job_id])
    assert len(summary.fitted) == 1, summary
    with ctx.session_factory() as session:
        fit = session.execute(select(Fit).where(Fit.sample_id == session.get(Job, job_id).sample_id)).scalar_one()
        placed = {(r.view_id, r.keypoint): r.from_proposal for r in session.execute(
            select(Click).where(Click.sample_id == fit.sample_id, Click.x_px.is_not(None))).scalars()}
    d = fit.diagnostics
    by_origin = d["residual_2d_by_origin"]
    n_accepted = sum(1 for f in placed.values() if f)
    assert by_origin["accepted"]["n"] == n_accepted > 0
    assert by_origin["clicked"]["n"] == len(placed) - n_accepted > 0
    assert d["mean_residual_2d_px"] == by_origin["clicked"]["mean_px"]
    assert {(view_ids[c], k) for c, k in d["accepted_2d"]} == {key for key, f in placed.items() if f}
