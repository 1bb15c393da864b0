"""FreiHAND-layout export of accepted samples: export, read back, and get the server's labels again.

A tiny synthetic capture (one green-screen training sequence, one evaluation sequence) is imported; each
sample is "fitted" with its ground-truth parameters (what a perfect fit records) and accepted by a
reviewer through the API; then `handloop export --format freihand` writes the layout.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from sqlalchemy import text
from typer.testing import CliRunner

from backend.cli.main import app
from backend.models.enums import Role
from backend.services.captures.samples import views_of
from backend.services.review.verification import HeuristicThresholds
from backend.settings import get_settings
from workers.capture import load_ground_truth, read_capture
from workers.export.freihand import mesh_from_freihand, read_freihand_set
from workers.export.meshes import read_mesh
from workers.geometry.projection import undistort_pixels
from workers.handmodel.loading import load_hand_model
from workers.tasks import records

runner = CliRunner()


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory) -> Path:
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    out = tmp_path_factory.mktemp("export-capture") / "cap"
    generate_capture(out, SynthConfig(num_sequences=2, frames_per_sequence=2, seed=4, width_px=64), workers=1)
    return out


def accept_all_with_true_fits(env, capture_dir: Path) -> dict[int, object]:
    """Import, record the ground-truth fit of every sample, accept each as a reviewer. sample id -> truth."""
    admin = env.headers(Role.admin)
    response = env.client.post("/api/admin/imports", headers=admin, json={"path": str(capture_dir), "project": "p"})
    assert response.status_code == 201, response.text
    capture = read_capture(capture_dir)
    index = env.client.get("/api/admin/exports/samples", headers=admin).json()
    assert index["count"] == 4
    truths = {}
    for row in index["samples"]:
        frame = capture.sequence(row["sequence"]).frames[row["frame_index"]]
        gt = load_ground_truth(frame, capture.hand_model.num_vertices)
        truths[row["sample_id"]] = gt
        with env.session() as s, s.begin():
            s.execute(text("UPDATE samples SET state = 'fitting' WHERE id = :i"),
                      {"i": row["sample_id"]})
        with env.session() as s, s.begin():
            views = views_of(s, row["sample_id"], with_masks=False)
            records.record_fit(
                s, row["sample_id"], params=gt.params.to_theta(),
                keypoints_m=gt.keypoints_3d, view_ious={v.id: 0.9 for v in views}, diagnostics={},
                inputs={"submission_ids": [0]}, model_file="handloop-builtin v1",
                thresholds=HeuristicThresholds())
    reviewer = env.headers(Role.reviewer)
    for _ in range(4):
        task = env.client.post("/api/review/next", headers=reviewer).json()
        decision = env.client.post(f"/api/review/samples/{task['sample_id']}/decision", headers=reviewer,
                                   json={"decision": "accept", "lease_token": task["lease_token"]})
        assert decision.status_code == 201, decision.text
    return truths


def export(env, out: Path, monkeypatch, *args: str):
    monkeypatch.setenv("HANDLOOP_DATABASE_URL", env.settings.resolved_database_url)
    monkeypatch.setenv("HANDLOOP_DATA_DIR", str(env.settings.data_dir))
    monkeypatch.delenv("HANDLOOP_MANO_PATH", raising=False)
    get_settings.cache_clear()
    try:
        return runner.invoke(app, ["export", "--format", "freihand", "--out", str(out), *args])
    finally:
        get_settings.cache_clear()


def test_export_then_read_back_gives_the_same_labels(sqlite_env, capture_dir, tmp_path, monkeypatch):
    env = sqlite_env
    truths = accept_all_with_true_fits(env, capture_dir)
    out = tmp_path / "freihand"
    result = export(env, out, monkeypatch, "--composites", "1", "--meshes", "ply,obj", "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    capture = read_capture(capture_dir)
    C = len(capture.cameras)
    assert summary["samples"] == {"training": 2 * C, "evaluation": 2 * C}
    assert summary["images"] == {"training": 2 * 2 * C, "evaluation": 2 * C}  # originals + one composite each
    assert summary["is_mano"] is False and summary["meshes"] == 8
    for name in ("training_K.json", "training_mano.json", "training_xyz.json", "training_scale.json",
                 "training_verts.json", "evaluation_K.json", "evaluation_mano.json", "evaluation_xyz.json",
                 "evaluation_scale.json", "evaluation_verts.json", "handloop_export.json", "README.txt"):
        assert (out / name).is_file(), name
    assert "not MANO" in (out / "README.txt").read_text()
    manifest = json.loads((out / "handloop_export.json").read_text())
    assert set(manifest["quality"]["streams"]) == {"heuristic", "manual", "annotated"}  # the audits' figures (issue 40)
    assert manifest["hand_model"]["is_mano"] is False and "HANDLOOP_MANO_PATH" in manifest["hand_model"]["notice"]

    arrays = load_hand_model(None)
    cameras = {c.name: c for c in capture.cameras}
    seen = set()
    for set_name in ("training", "evaluation"):
        data = read_freihand_set(out, set_name)
        assert len(data) == 2 * C and len(list((out / set_name / "rgb").iterdir())) == summary["images"][set_name]
        for i, entry in enumerate(data.entries):
            gt = truths[entry["sample_id"]]
            camera = cameras[entry["camera"]]
            c = capture.camera_names.index(entry["camera"])
            seen.add((entry["sample_id"], entry["camera"]))
            # The server's label (world frame) comes back from the camera-frame file and the manifest.
            np.testing.assert_allclose(data.world_keypoints(i), gt.keypoints_3d, atol=1e-9)
            verts_world = (data.verts[i] - camera.t) @ camera.R
            np.testing.assert_allclose(verts_world, gt.vertices, atol=2e-6)  # ground truth is stored float32
            np.testing.assert_allclose(data.K[i], camera.K)
            # FreiHAND's projection K @ xyz lands on the ground-truth keypoints of the undistorted image.
            uv = (data.xyz[i] @ data.K[i].T)[:, :2] / data.xyz[i][:, 2:]
            np.testing.assert_allclose(uv, undistort_pixels(gt.keypoints_2d[c], camera), atol=1e-4)
            assert data.scale[i] == pytest.approx(np.linalg.norm(gt.keypoints_3d[9] - gt.keypoints_3d[10]))
            # The 61 MANO-style numbers pose the model back onto the same keypoints and mesh.
            xyz, verts = mesh_from_freihand(arrays, data.mano[i], data.K[i])
            np.testing.assert_allclose(xyz, data.xyz[i], atol=1e-6)
            np.testing.assert_allclose(verts, data.verts[i], atol=1e-6)
            mask = cv2.imread(str(out / set_name / "mask" / f"{i:08d}.jpg"), cv2.IMREAD_GRAYSCALE)
            image = cv2.imread(str(out / set_name / "rgb" / f"{i:08d}.jpg"))
            assert mask.shape == image.shape[:2] == (camera.height, camera.width)
            inside = np.round(uv[gt.visibility[c]]).astype(int)
            inside = inside[(inside[:, 0] >= 0) & (inside[:, 0] < camera.width) & (inside[:, 1] >= 0)
                            & (inside[:, 1] < camera.height)]
            if len(inside):  # the model's silhouette covers the visible keypoints (within a pixel)
                grown = cv2.dilate((mask > 127).astype(np.uint8), np.ones((3, 3), np.uint8))
                assert grown[inside[:, 1], inside[:, 0]].mean() > 0.8
        for entry in data.entries:
            mesh_vertices, faces = read_mesh(out / entry["meshes"][0])
            np.testing.assert_allclose(mesh_vertices, truths[entry["sample_id"]].vertices, atol=2e-6)
            assert faces.shape == arrays.faces.shape
    assert len(seen) == 4 * C

    # The evaluation labels as a perfect prediction: `handloop eval` on the export scores AUC 1.
    data = read_freihand_set(out, "evaluation")
    (tmp_path / "pred.json").write_text(json.dumps([data.xyz.tolist(), data.verts.tolist()]))
    scored = runner.invoke(app, ["eval", str(tmp_path / "pred.json"), str(out), "--json"])
    assert scored.exit_code == 0, scored.output
    scores = json.loads(scored.stdout.strip().splitlines()[-1])
    assert scores["xyz_auc3d"] == 1.0 and scores["mesh_mean3d"] == 0.0 and scores["f_score_5"] == 1.0


def test_dataset_endpoint_names_the_hand_model(sqlite_env, capture_dir):
    env = sqlite_env
    accept_all_with_true_fits(env, capture_dir)
    data = env.client.get("/api/admin/exports/dataset", headers=env.headers(Role.admin)).json()
    assert data["count"] == 4 and data["hand_models"] == ["handloop-builtin v1"]
    assert {s["stream"] for s in data["samples"]} == {"annotated"}
    missing = env.client.get("/api/admin/exports/dataset?project=nope", headers=env.headers(Role.admin))
    assert missing.status_code == 404 and "project 'nope' not found" in missing.json()["detail"]
    bad = env.client.get("/api/admin/exports/dataset?up_to_round=-1", headers=env.headers(Role.admin))
    assert bad.status_code == 422
    beyond = env.client.get("/api/admin/exports/dataset?up_to_round=99", headers=env.headers(Role.admin))
    assert beyond.status_code == 404 and "round D_99 not found" in beyond.json()["detail"], beyond.text
    assert env.client.get("/api/admin/exports/dataset?up_to_round=0", headers=env.headers(Role.admin)).json()[
        "count"] == 4


def test_bad_arguments_are_refused_and_write_nothing(sqlite_env, capture_dir, tmp_path, monkeypatch):
    env = sqlite_env
    out = tmp_path / "x"
    empty = export(env, out, monkeypatch)
    assert empty.exit_code == 2 and "nothing to export" in empty.output and not out.exists()
    accept_all_with_true_fits(env, capture_dir)
    for args, message in ((["--format", "coco"], "--format must be one of freihand"),
                          (["--composites", "9"], "composites must be in 0..8"),
                          (["--meshes", "stl"], "mesh formats must be among"),
                          (["--jpeg-quality", "10"], "jpeg_quality must be in 50..100"),
                          (["--project", "nope"], "project 'nope' not found")):
        result = export(env, out, monkeypatch, *args)
        assert result.exit_code == 2 and message in result.output, (args, result.output)
        assert not out.exists()
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    busy = export(env, out, monkeypatch)
    assert busy.exit_code == 2 and "not empty" in busy.output and (out / "keep.txt").exists()
    # A broken image fails the export and leaves neither the folder nor a partial one behind.
    target = tmp_path / "y"
    with env.session() as s:
        key = s.execute(text("SELECT image_key FROM views ORDER BY id DESC LIMIT 1")).scalar()
    env.client.app.state.storage.put_bytes(key, b"not an image")
    broken = export(env, target, monkeypatch)
    assert broken.exit_code == 2 and "cannot be decoded" in broken.output
    assert not target.exists() and not [p for p in tmp_path.iterdir() if ".partial-" in p.name]
    replaced = export(env, out, monkeypatch, "--force", "--up-to-round", "0", "--meshes", "none")
    assert replaced.exit_code == 2 and "cannot be decoded" in replaced.output and (out / "keep.txt").exists()
