"""Real-sized views end to end (issue 18): a 2048 px capture with a 640 px working width is imported, its
samples get fits and reach review; the review overlay draws the fit in full-resolution pixels of the 2048 px
views, the pages get the working-width copy (the original on ?full=true), and the FreiHAND export writes the
2048 px originals with the full-resolution intrinsics."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from sqlalchemy import text

from backend.models.enums import Role
from backend.services.captures.samples import views_of
from backend.services.review.verification import HeuristicThresholds
from tests.backend.services.exports.test_export import export
from tests.support.real_sized import FULL_WIDTH, upscaled_capture
from workers.capture import load_ground_truth, read_capture
from workers.export.freihand import read_freihand_set
from workers.geometry.projection import undistort_pixels
from workers.tasks import records

WORKING_WIDTH = 640


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory) -> Path:
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    root = tmp_path_factory.mktemp("real-sized")
    generate_capture(root / "small", SynthConfig(num_sequences=1, frames_per_sequence=2, seed=8, width_px=256),
                     workers=1)
    return upscaled_capture(root / "small", root / "big", working_width_px=WORKING_WIDTH)


def test_review_overlay_views_and_export_at_2048_px(sqlite_env, capture_dir: Path, tmp_path: Path,
                                                     monkeypatch) -> None:
    env = sqlite_env
    admin, reviewer = env.headers(Role.admin), env.headers(Role.reviewer)
    response = env.client.post("/api/admin/imports", headers=admin, json={"path": str(capture_dir), "project": "big"})
    assert response.status_code == 201, response.text
    capture = read_capture(capture_dir)
    cameras = {c.name: c for c in capture.cameras}
    assert {c.width for c in capture.cameras} == {FULL_WIDTH}
    index = env.client.get("/api/admin/exports/samples", headers=admin).json()
    truths = {}
    for row in index["samples"]:  # each sample "fitted" with its ground truth (what a perfect fit records)
        gt = load_ground_truth(capture.sequence(row["sequence"]).frames[row["frame_index"]])
        truths[row["sample_id"]] = gt
        with env.session() as s, s.begin():
            s.execute(text("UPDATE samples SET state = 'fitting' WHERE id = :i"), {"i": row["sample_id"]})
        with env.session() as s, s.begin():
            views = views_of(s, row["sample_id"], with_masks=False)
            records.record_fit(s, row["sample_id"], params=gt.params.to_theta(),
                               keypoints_m=gt.keypoints_3d, view_ious={v.id: 0.9 for v in views}, diagnostics={},
                               inputs={"submission_ids": [0]}, model_file="handloop-builtin v1",
                               thresholds=HeuristicThresholds())
    for _ in truths:
        task = env.client.post("/api/review/next", headers=reviewer).json()
        gt = truths[task["sample_id"]]
        overlay = env.client.get(f"/api/review/samples/{task['sample_id']}/overlay", headers=reviewer)
        assert overlay.status_code == 200, overlay.text
        for view in overlay.json()["views"]:
            c = list(gt.camera_names).index(view["camera"])
            assert (view["width"], view["height"]) == (FULL_WIDTH, cameras[view["camera"]].height)
            drawn = np.array([p if p is not None else [np.nan, np.nan] for p in view["fit_keypoints_px"]], float)
            # the overlay in full-resolution pixels: on the 2048 px view's keypoints, not on the working copy's
            np.testing.assert_allclose(drawn[gt.visibility[c]], gt.keypoints_2d[c][gt.visibility[c]], atol=0.05)
        shown = env.client.get(f"/api/files/views/{task['views'][0]['id']}/image", headers=reviewer)
        original = env.client.get(f"/api/files/views/{task['views'][0]['id']}/image?full=true", headers=reviewer)
        assert shown.status_code == original.status_code == 200
        small = cv2.imdecode(np.frombuffer(shown.content, np.uint8), cv2.IMREAD_COLOR)
        big = cv2.imdecode(np.frombuffer(original.content, np.uint8), cv2.IMREAD_COLOR)
        assert small.shape[1] == WORKING_WIDTH and big.shape[1] == FULL_WIDTH
        decision = env.client.post(f"/api/review/samples/{task['sample_id']}/decision", headers=reviewer,
                                   json={"decision": "accept", "lease_token": task["lease_token"]})
        assert decision.status_code == 201, decision.text

    out = tmp_path / "freihand"
    result = export(env, out, monkeypatch, "--meshes", "none", "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["samples"]["training"] == 2 * len(cameras)
    data = read_freihand_set(out, "training")
    for i, entry in enumerate(data.entries):
        camera, gt = cameras[entry["camera"]], truths[entry["sample_id"]]
        c = list(gt.camera_names).index(entry["camera"])
        np.testing.assert_allclose(data.K[i], camera.K)  # the full-resolution intrinsics
        image = cv2.imread(str(out / "training" / "rgb" / f"{i:08d}.jpg"))
        assert image.shape[:2] == (camera.height, camera.width) == (camera.height, FULL_WIDTH)
        uv = (data.xyz[i] @ data.K[i].T)[:, :2] / data.xyz[i][:, 2:]
        np.testing.assert_allclose(uv, undistort_pixels(gt.keypoints_2d[c], camera), atol=1e-4)
