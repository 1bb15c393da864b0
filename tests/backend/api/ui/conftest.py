"""A tiny synthetic capture (with ground truth) imported into the app, and helpers that walk a sample
through annotation and a fit (recorded as a worker would, from the ground-truth parameters) into review."""

from __future__ import annotations

import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

from backend.models.enums import Role

REPO = Path(__file__).resolve().parents[4]
HANDLOOP = str(Path(sys.executable).parent / "handloop")


@pytest.fixture(scope="session")
def ui_capture(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ui-capture") / "tiny"
    result = subprocess.run([HANDLOOP, "synth", "--out", str(out), "--sequences", "1", "--frames", "3", "--seed", "5",
                             "--width", "96", "--workers", "1"], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    return out


class UI:
    @staticmethod
    def import_capture(env, capture: Path) -> None:
        response = env.client.post("/api/admin/imports", headers=env.headers(Role.admin),
                                   json={"path": str(capture), "project": "ui"})
        assert response.status_code == 201, response.text

    @staticmethod
    def ground_truth(capture: Path, frame_index: int):
        from workers.capture import read_capture
        from workers.capture.reader import load_ground_truth

        cap = read_capture(capture, check_images=False)
        return cap, load_ground_truth(cap.sequences[0].frames[frame_index])

    @staticmethod
    def clicks_from_truth(task: dict, capture: Path) -> list[dict]:
        """The sparse keypoints of every view at their true (projected) positions."""
        _, gt = UI.ground_truth(capture, task["frame_index"])
        by_camera = {name: c for c, name in enumerate(gt.camera_names)}
        clicks = []
        for view in task["views"]:
            uv = gt.keypoints_2d[by_camera[view["camera"]]]
            for k in task["keypoints_to_click"]:
                x, y = (float(v) for v in uv[k])
                if -0.5 <= x <= view["width"] - 0.5 and -0.5 <= y <= view["height"] - 0.5:
                    clicks.append({"view_id": view["id"], "keypoint": k, "x": x, "y": y, "visibility": "visible"})
                else:
                    clicks.append({"view_id": view["id"], "keypoint": k, "visibility": "not_annotated"})
        return clicks

    @staticmethod
    def submit(env, task: dict, capture: Path, role: Role = Role.annotator) -> dict:
        body = {"submission_id": uuid.uuid4().hex, "lease_token": task["lease_token"], "time_spent_s": 30.0,
                "clicks": UI.clicks_from_truth(task, capture)}
        response = env.client.post(f"/api/annotate/samples/{task['sample_id']}/submissions", json=body,
                                   headers=env.headers(role))
        assert response.status_code == 201, response.text
        return response.json()

    @staticmethod
    def record_truth_fit(env, sample_id: int, frame_index: int, capture: Path, submission_id: int,
                         offset_m: float = 0.0, iou: float = 0.9, mesh_offset_m: float | None = 0.0) -> int:
        """A fit with the ground-truth parameters (shifted by `offset_m` along x), as a worker records it: with
        the true mesh shifted by `mesh_offset_m` (None: no mesh stored, as fits before revision 0012)."""
        from backend.services.captures.samples import views_of
        from backend.services.review.verification import HeuristicThresholds
        from workers.tasks import records

        _, gt = UI.ground_truth(capture, frame_index)
        shift = np.array([offset_m, 0.0, 0.0])
        params = np.concatenate([gt.betas, gt.pose, gt.global_orient, gt.transl + shift])
        vertices = None if mesh_offset_m is None else gt.vertices + np.array([mesh_offset_m, 0.0, 0.0])
        with env.session() as session, session.begin():
            views = views_of(session, sample_id, with_masks=False)
            fit = records.record_fit(
                session, sample_id, params=params.tolist(), keypoints_m=(gt.keypoints_3d + shift).tolist(),
                view_ious={v.id: iou for v in views}, diagnostics={"loss": 0.1},
                inputs={"submission_ids": [submission_id]}, model_file="handloop-builtin v1",
                thresholds=HeuristicThresholds(), vertices_m=vertices)
            return fit.id

    @staticmethod
    def in_review(env, capture: Path, offset_m: float = 0.0, mesh_offset_m: float | None = 0.0) -> dict:
        """Import, annotate one sample from the truth, fit it; the reviewer's task for it."""
        UI.import_capture(env, capture)
        task = env.client.post("/api/annotate/next", headers=env.headers(Role.annotator)).json()
        submission = UI.submit(env, task, capture)
        UI.record_truth_fit(env, task["sample_id"], task["frame_index"], capture, submission["id"], offset_m,
                            mesh_offset_m=mesh_offset_m)
        review = env.client.post("/api/review/next", headers=env.headers(Role.reviewer))
        assert review.status_code == 200, review.text
        return review.json()


@pytest.fixture
def ui() -> type[UI]:
    return UI
