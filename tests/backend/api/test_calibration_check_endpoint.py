"""GET /api/admin/projects/{id}/calibration-check: the calibration check from annotators' visible clicks."""

from __future__ import annotations

import uuid
from pathlib import Path

import cv2
import numpy as np
from sqlalchemy import select

from backend.models.enums import Role
from workers.capture import load_ground_truth, read_capture


def _import(env, tmp_path: Path) -> tuple[int, object]:
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    capture = tmp_path / "capture"
    generate_capture(capture, SynthConfig(num_sequences=1, frames_per_sequence=12, seed=11, width_px=320), workers=1)
    response = env.client.post("/api/admin/imports", headers=env.headers(Role.admin),
                               json={"path": str(capture), "project": "check"})
    assert response.status_code == 201, response.text
    return response.json()["project_id"], read_capture(capture)


def _annotate_from_ground_truth(env, capture, from_proposal: bool = False) -> None:
    frames = capture.sequences[0].frames
    for _ in frames:
        task = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
        gt = load_ground_truth(frames[task["frame_index"]])
        clicks = []
        for view in task["views"]:
            c = list(gt.camera_names).index(view["camera"])
            for k in task["keypoints_to_click"]:
                if gt.visibility[c, k]:
                    x, y = gt.keypoints_2d[c, k]
                    clicks.append({"view_id": view["id"], "keypoint": k, "x": float(x), "y": float(y),
                                   "visibility": "visible", "from_proposal": from_proposal})
                else:
                    clicks.append({"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"})
        body = {"submission_id": uuid.uuid4().hex, "lease_token": task["lease_token"], "time_spent_s": 10.0,
                "clicks": clicks}
        response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions",
                                   headers=env.headers(Role.annotator), json=body)
        assert response.status_code == 201, response.text


def test_check_from_clicks_flags_the_turned_camera(env, tmp_path: Path) -> None:
    from backend.models.capture import CameraCalibration

    project_id, capture = _import(env, tmp_path)
    url = f"/api/admin/projects/{project_id}/calibration-check"
    before = env.client.get(url, headers=env.headers(Role.admin))
    assert before.status_code == 200, before.text
    assert before.json()["frames"] == 0 and before.json()["flagged"] == []
    assert "no visible clicks yet" in before.json()["notes"][0]

    _annotate_from_ground_truth(env, capture)
    report = env.client.get(url, headers=env.headers(Role.admin)).json()
    assert report["source"] == "clicks" and report["frames"] == 12
    assert report["flagged"] == [] and len(report["pairs"]) == 28

    with env.session() as session, session.begin():
        row = session.execute(select(CameraCalibration).where(CameraCalibration.project_id == project_id,
                                                              CameraCalibration.name == "cam4")).scalar_one()
        delta = cv2.Rodrigues(np.deg2rad(2.0) * np.array([[0.0], [1.0], [0.0]]))[0]
        row.R, row.t = (delta @ np.asarray(row.R)).tolist(), (delta @ np.asarray(row.t)).tolist()
    report = env.client.get(url, headers=env.headers(Role.admin)).json()
    assert report["flagged"] == ["cam4"], report
    assert env.client.get("/api/admin/projects/999/calibration-check",
                          headers=env.headers(Role.admin)).status_code == 404


def test_accepted_proposals_are_not_judged_as_clicks(env, tmp_path: Path) -> None:
    """Points accepted from proposals are the proposals' own geometry (a fit's projection agrees with every camera
    by construction): the check judges only points a person placed (issue 38: 0.00 px on views nobody clicked)."""
    project_id, capture = _import(env, tmp_path)
    _annotate_from_ground_truth(env, capture, from_proposal=True)
    report = env.client.get(f"/api/admin/projects/{project_id}/calibration-check", headers=env.headers(Role.admin))
    assert report.status_code == 200, report.text
    assert report.json()["frames"] == 0 and "no visible clicks yet" in report.json()["notes"][0]
