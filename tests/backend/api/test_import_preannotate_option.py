"""`POST /api/admin/imports` with `preannotate` (the admin page's checkbox), on SQLite and PostgreSQL: true imports
the samples unlabeled and queues their pre-annotation job (round 0), or refuses the import (503, nothing written)
where the detector cannot run; false imports into the annotators' queue whatever the server's setting says."""

from __future__ import annotations

import pytest
from sqlalchemy import func, select

from backend.models.capture import Project, Sample
from backend.models.enums import Role
from backend.models.jobs import Job
from backend.services.rounds import preannotation
from tests.support.live_stack import tiny_capture

MISSING = "the hand landmark model file is missing: install it with scripts/fetch_models.sh"


@pytest.fixture()
def capture(capture_cache):
    return tiny_capture(capture_cache, frames=4)


def _states(env) -> dict[str, int]:
    with env.session() as s:
        return dict(s.execute(select(Sample.state, func.count()).group_by(Sample.state)).all())


def _import(env, body: dict):
    return env.client.post("/api/admin/imports", headers=env.headers(Role.admin), json=body)


@pytest.mark.parametrize("queue_for_annotation", [True, False])
def test_preannotate_true_queues_round_0_for_the_unlabeled_samples(env, capture, monkeypatch, queue_for_annotation):
    monkeypatch.setattr(preannotation, "detector_problem", lambda: None)
    response = _import(env, {"path": str(capture), "preannotate": True, "queue_for_annotation": queue_for_annotation})
    assert response.status_code == 201, response.text
    body = response.json()
    job_id = body["preannotation_job_id"]
    assert body["preannotation"] == f"job {job_id} queued" and env.queue.enqueued == [(job_id, "preannotate")]
    assert _states(env) == {"unlabeled": 4}
    with env.session() as s:
        job = s.get(Job, job_id)
        assert (job.kind, job.state) == ("preannotate", "queued")
        assert job.payload["project_id"] == body["project_id"] and len(job.payload["sample_ids"]) == 4
        # the samples the reviewers' queue does not take: to the annotators, or kept for round 1
        assert job.payload["rest"] == ("annotate" if queue_for_annotation else "keep")
    progress = env.client.get(f"/api/admin/jobs/{job_id}", headers=env.headers(Role.admin)).json()
    assert (progress["state"], progress["progress"]) == ("queued", 0.0)  # what the page's live bar starts from


def test_preannotate_true_without_the_detector_refuses_and_writes_nothing(env, capture, monkeypatch):
    monkeypatch.setattr(preannotation, "detector_problem", lambda: MISSING)
    response = _import(env, {"path": str(capture), "preannotate": True})
    assert response.status_code == 503, response.text
    assert MISSING in response.json()["detail"] and "nothing was imported" in response.json()["detail"]
    with env.session() as s:
        assert s.execute(select(func.count()).select_from(Project)).scalar_one() == 0
        assert s.execute(select(func.count()).select_from(Job)).scalar_one() == 0
    assert env.queue.enqueued == []


def test_preannotate_false_overrides_the_servers_setting(env_with, db_url, tmp_path, capture, monkeypatch):
    monkeypatch.setattr(preannotation, "detector_problem", lambda: None)
    env = env_with(db_url, tmp_path, preannotate_on_import=True)
    response = _import(env, {"path": str(capture), "preannotate": False})
    assert response.status_code == 201, response.text
    assert response.json()["preannotation"] is None and response.json()["preannotation_job_id"] is None
    assert _states(env) == {"needs_annotation": 4} and env.queue.enqueued == []
    # left out, the setting decides (as before the option)
    response = _import(env, {"path": str(capture), "project": "by-setting"})
    assert response.status_code == 201 and response.json()["preannotation_job_id"] is not None, response.text
