"""Pre-annotation through the API: the admin's routes and their roles, the refusal where the detector is missing,
HANDLOOP_PREANNOTATE_ON_IMPORT, the "D" proposals of a detector fit sent back by a reviewer, and detector fits
accepted by reviewers counted in D_0 with their provenance in the export. The detector is the ground-truth
fake (tests/support/detector_fake.py); the job runs in-process (workers.tasks.preannotate)."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from backend.app import create_app
from backend.models.capture import Project, Sample, Sequence
from backend.models.fits import Fit
from backend.models.jobs import Job
from backend.services.display.detection_points import fitted_detections
from backend.services.display.fit_agreement import fit_confidences
from backend.services.display.view_geometry import view_cameras
from backend.services.jobs.jobs import InMemoryJobQueue
from backend.services.rounds import preannotation
from backend.settings import Settings
from tests.support.detector_fake import FakeDetector
from tests.support.live_stack import TEST_SETTINGS, USERS, prepare_database, tiny_capture
from workers.geometry.projection import project_visible as project
from workers.tasks import preannotate
from workers.tasks.context import build_context

MISSING = "the hand landmark model file is missing: install it with scripts/fetch_models.sh"


@pytest.fixture
def make_world(tmp_path, capture_cache, monkeypatch):
    """make_world(**settings) -> (client, headers by role, queue, worker context, capture dir, fake)."""
    stack = []

    @contextmanager
    def app_for(settings):
        queue = InMemoryJobQueue()
        app = create_app(settings, job_queue=queue)
        with TestClient(app) as client:
            yield app, client, queue
        app.state.engine.dispose()

    def make(**overrides):
        capture = tiny_capture(capture_cache, frames=4)
        settings = Settings(data_dir=tmp_path / "data", review_min_time_gap_s=0.0, review_min_pose_distance=0.0,
                            **{**TEST_SETTINGS, "import_roots": [capture.parent], **overrides})
        prepare_database(settings, capture, queue_for_annotation=False)
        manager = app_for(settings)
        _, client, queue = manager.__enter__()
        stack.append(manager)
        headers = {}
        for role, user in USERS.items():
            token = client.post("/api/auth/token", data={"username": user.email, "password": user.password})
            headers[role] = {"Authorization": f"Bearer {token.json()['access_token']}"}
        fake = FakeDetector(capture)
        monkeypatch.setattr(preannotate, "detect", fake)
        monkeypatch.setattr(preannotation, "detector_problem", lambda: None)
        monkeypatch.setattr(preannotation, "quick_detector_problem", lambda: None)  # the admin page's status
        return client, headers, queue, build_context(settings, job_queue=queue), capture, fake

    yield make
    for manager in reversed(stack):
        manager.__exit__(None, None, None)


def _project_id(ctx, name: str = "live") -> int:
    with ctx.session_factory() as session:
        return session.execute(select(Project.id).where(Project.name == name)).scalar_one()


def _states(ctx, project: str = "live") -> dict[str, int]:
    with ctx.session_factory() as session:
        return dict(session.execute(select(Sample.state, func.count()).join(Sequence)
                                    .join(Project).where(Project.name == project).group_by(Sample.state)).all())


def test_only_admins_see_the_detector_and_launch_pre_annotation(make_world):
    client, headers, queue, ctx, _, _ = make_world()
    body = {"project_id": _project_id(ctx)}
    for role in ("reviewer", "annotator"):
        assert client.get("/api/admin/preannotation", headers=headers[role]).status_code == 403
        assert client.post("/api/admin/preannotation", json=body, headers=headers[role]).status_code == 403
    assert client.post("/api/admin/preannotation", json=body).status_code == 401
    status = client.get("/api/admin/preannotation", headers=headers["admin"])
    assert status.status_code == 200, status.text
    assert status.json() == {"available": True, "reason": None, "projects": [
        {"project_id": body["project_id"], "name": "live", "samples": 4, "unlabeled": 4, "running_job_id": None}]}
    launched = client.post("/api/admin/preannotation", json=body, headers=headers["admin"])
    assert launched.status_code == 202, launched.text
    assert launched.json()["samples"] == 4 and queue.enqueued == [(launched.json()["job_id"], "preannotate")]
    with ctx.session_factory() as session:  # unpicked samples stay for the next round unless the admin says otherwise
        assert session.get(Job, launched.json()["job_id"]).payload["rest"] == "keep"
    again = client.post("/api/admin/preannotation", json=body, headers=headers["admin"])
    assert again.status_code == 409 and "already being pre-annotated" in again.json()["detail"]
    listed = client.get("/api/admin/preannotation", headers=headers["admin"]).json()["projects"]
    assert listed[0]["running_job_id"] == launched.json()["job_id"]


def test_bad_requests_are_refused_with_what_is_wrong(make_world):
    client, headers, _, ctx, _, _ = make_world()
    admin = headers["admin"]
    cases = [({"project_id": 0}, 422, "project_id"), ({"project_id": 999}, 404, "project 999 not found"),
             ({"project_id": _project_id(ctx), "rest": "drop"}, 422, "rest"),
             ({"project_id": _project_id(ctx), "sample_ids": []}, 422, "sample_ids"),
             ({"project_id": _project_id(ctx), "sample_ids": [424242]}, 404, "samples not in project")]
    for body, status, message in cases:
        response = client.post("/api/admin/preannotation", json=body, headers=admin)
        assert response.status_code == status and message in response.text, (body, response.text)
    with ctx.session_factory() as session:
        assert session.execute(select(func.count()).select_from(Job)).scalar_one() == 0


def test_without_the_detector_the_action_is_refused_with_its_sentence(make_world, monkeypatch):
    client, headers, queue, ctx, _, _ = make_world()
    monkeypatch.setattr(preannotation, "detector_problem", lambda: MISSING)
    monkeypatch.setattr(preannotation, "quick_detector_problem", lambda: MISSING)
    status = client.get("/api/admin/preannotation", headers=headers["admin"]).json()
    assert (status["available"], status["reason"]) == (False, MISSING)
    refused = client.post("/api/admin/preannotation", json={"project_id": _project_id(ctx)}, headers=headers["admin"])
    assert refused.status_code == 503 and MISSING in refused.json()["detail"]
    assert queue.enqueued == [] and _states(ctx) == {"unlabeled": 4}


@pytest.mark.parametrize("detector", ["present", "missing"])
def test_the_setting_pre_annotates_an_import(make_world, monkeypatch, detector):
    client, headers, queue, ctx, capture, _ = make_world(preannotate_on_import=True)
    if detector == "missing":
        monkeypatch.setattr(preannotation, "detector_problem", lambda: MISSING)
    imported = client.post("/api/admin/imports", json={"path": str(capture), "project": "second"},
                           headers=headers["admin"])
    assert imported.status_code == 201, imported.text
    body = imported.json()
    if detector == "missing":  # the import is as without the setting, and says why
        assert body["preannotation"] == f"not run: {MISSING}" and body["preannotation_job_id"] is None
        assert _states(ctx, "second") == {"needs_annotation": 4} and queue.enqueued == []
        return
    job_id = body["preannotation_job_id"]
    assert body["preannotation"] == f"job {job_id} queued" and queue.enqueued == [(job_id, "preannotate")]
    assert _states(ctx, "second") == {"unlabeled": 4}  # the job routes them
    result = preannotate.run_preannotation_job(ctx, job_id)
    assert result["fitted"] == 4
    states = _states(ctx, "second")
    assert set(states) <= {"in_review", "needs_annotation"} and states.get("in_review", 0) >= 2, states


def test_the_setting_is_off_by_default(make_world):
    client, headers, queue, ctx, capture, _ = make_world()
    imported = client.post("/api/admin/imports", json={"path": str(capture), "project": "plain"},
                           headers=headers["admin"]).json()
    assert imported["preannotation"] is None and queue.enqueued == []
    assert _states(ctx, "plain") == {"needs_annotation": 4}


def test_sent_back_detector_fits_reach_annotators_with_d_proposals_and_accepted_ones_form_d0(make_world):
    client, headers, _, ctx, _, _ = make_world()
    launched = client.post("/api/admin/preannotation", json={"project_id": _project_id(ctx), "rest": "keep"},
                           headers=headers["admin"]).json()
    preannotate.run_preannotation_job(ctx, launched["job_id"])
    assert _states(ctx) == {"in_review": 4}
    reviewer, annotator = headers["reviewer"], headers["annotator"]
    task = client.post("/api/review/next", headers=reviewer).json()
    sent_back = client.post(f"/api/review/samples/{task['sample_id']}/decision", headers=reviewer,
                            json={"decision": "annotate", "reason": "thumb on the wrong side",
                                  "lease_token": task["lease_token"]})
    assert sent_back.status_code == 201, sent_back.text
    work = client.post("/api/annotate/next", headers=annotator).json()
    assert work["sample_id"] == task["sample_id"]
    proposals = client.get(f"/api/annotate/samples/{work['sample_id']}/proposals", headers=annotator).json()
    kinds = [s["kind"] for s in proposals["sources"]]
    # The fit of the detector's keypoints is offered first (nearer the truth than one view's detection), then
    # the detections themselves.
    assert kinds == ["fit", "detector"] and proposals["review_note"] == "thumb on the wrong side"
    fitted, detector = proposals["sources"]
    with ctx.session_factory() as session:
        fit = session.get(Fit, session.get(Sample, work["sample_id"]).current_fit_id)
        detection = fit.inputs["detection"]
        cameras = {c.view_id: c for c in view_cameras(session, work["sample_id"])}
    for view_id, cam in cameras.items():
        expected = project(np.asarray(fit.keypoints_m, float), cam)
        assert np.array(fitted["views"][str(view_id)], float) == pytest.approx(expected, abs=0.01)
    # F carries the fit's agreement with the detections it was fitted to as its confidence (issue 38).
    projected = {v: project(np.asarray(fit.keypoints_m, float), cam) for v, cam in cameras.items()}
    agreement = fit_confidences(projected, fitted_detections(fit.inputs, list(cameras.values())))
    assert fitted["confidences"] == agreement and any(c is not None for c in agreement), fitted["confidences"]
    assert detector["label"].startswith("detector (confidence")
    assert detector["confidences"] == pytest.approx(np.nan_to_num(np.array(detection["confidence"], float)), abs=1e-4)
    for c, view_id in enumerate(detection["view_ids"]):
        own = np.array(detection["views"][c]["keypoints_px"], float)
        shown = detector["views"][str(view_id)]
        for k in range(21):
            if detection["inliers"][k][c]:  # the view's own detection where it agreed with the others
                assert shown[k] == pytest.approx(own[k], abs=0.01)
            else:  # an outlier view shows the triangulated keypoint instead
                assert shown[k] is None or np.linalg.norm(np.subtract(shown[k], own[k])) > 8.0
    # The reviewers accept the rest: D_0 is made of verified detector fits (stream "manual"), with provenance.
    accepted = 0
    while (task := client.post("/api/review/next", headers=reviewer)).status_code == 200:
        task = task.json()
        decided = client.post(f"/api/review/samples/{task['sample_id']}/decision", headers=reviewer,
                              json={"decision": "accept", "lease_token": task["lease_token"]})
        assert decided.status_code == 201 and decided.json()["stream"] == "manual", decided.text
        accepted += 1
    assert accepted == 3
    stats = client.get("/api/admin/rounds/statistics", headers=headers["admin"]).json()
    assert [(r["index"], r["added"]["manual"], r["added_total"]) for r in stats["rounds"]] == [(0, 3, 3)]
    dataset = client.get("/api/admin/exports/dataset", headers=headers["admin"]).json()
    assert dataset["count"] == 3
    assert {(s["round"], s["stream"], s["fit"]["source"]) for s in dataset["samples"]} == {(0, "manual", "detector")}


def test_reliability_of_the_detector_and_triangulation_confidences_against_the_ground_truth(make_world):
    client, headers, _, ctx, _, _ = make_world()
    empty = client.get("/api/admin/reliability", headers=headers["admin"]).json()
    assert empty["rounds"] == [] and empty["references"] == {"ground_truth": 0, "accepted_fit": 0}
    launched = client.post("/api/admin/preannotation", json={"project_id": _project_id(ctx)},
                           headers=headers["admin"]).json()
    preannotate.run_preannotation_job(ctx, launched["job_id"])
    out = client.get("/api/admin/reliability?bins=10", headers=headers["admin"]).json()
    assert out["references"] == {"ground_truth": 4, "accepted_fit": 0} and [r["index"] for r in out["rounds"]] == [0]
    sources = out["rounds"][0]["sources"]
    detector, triangulation = sources["detector"], sources["triangulation"]
    assert detector["n"] == 4 * 8 * 21 and detector["counts"][9] == detector["n"]  # the fake scores every point 0.9
    # 7 views within ~1 px and one 40 px off in x and y: a mean of (7 * 1.25 + 56.6) / 8 px or so.
    assert 5.0 < detector["mean_error"][9] < 12.0
    # mm, at 160 px wide views (4.5 mm when written): the triangulation left the 40 px outlier view out.
    assert triangulation["n"] == 4 * 21 and triangulation["mean_error"][9] < 8.0
    assert sources["mvnet"]["n"] == 0 and out["units"] == {"detector": "px", "triangulation": "mm", "mvnet": "mm"}
    bad = client.get("/api/admin/reliability?bins=0", headers=headers["admin"])
    assert bad.status_code == 422
