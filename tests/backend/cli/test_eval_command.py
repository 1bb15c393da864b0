"""`handloop eval PRED GT`: FreiHAND's file formats in, official score names out, clear errors on bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from backend.cli.main import app

runner = CliRunner()


def write_gt(folder: Path, xyz: np.ndarray, verts: np.ndarray, set_name: str = "evaluation") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{set_name}_xyz.json").write_text(json.dumps(xyz.tolist()))
    (folder / f"{set_name}_verts.json").write_text(json.dumps(verts.tolist()))
    return folder


@pytest.fixture
def dataset(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    xyz = rng.normal(0, 0.04, (4, 21, 3)) + np.array([0, 0, 0.5])
    verts = rng.normal(0, 0.04, (4, 50, 3)) + np.array([0, 0, 0.5])
    return write_gt(tmp_path / "gt", xyz, verts), xyz, verts


def last_json(output: str) -> dict:
    return json.loads(output.strip().splitlines()[-1])


def test_eval_reports_the_official_names(dataset, tmp_path):
    gt, xyz, verts = dataset
    pred = tmp_path / "pred.json"
    shift = np.array([0.01, 0, 0])
    pred.write_text(json.dumps([(xyz + shift).tolist(), (verts + shift).tolist()]))
    scores_txt = tmp_path / "scores.txt"
    result = runner.invoke(app, ["eval", str(pred), str(gt), "--json", "--scores-txt", str(scores_txt)])
    assert result.exit_code == 0, result.output
    record = last_json(result.stdout)
    for key in ("xyz_mean3d", "xyz_auc3d", "xyz_al_mean3d", "xyz_al_auc3d", "mesh_mean3d", "mesh_auc3d",
                "mesh_al_mean3d", "mesh_al_auc3d", "f_score_5", "f_al_score_5", "f_score_15", "f_al_score_15"):
        assert key in record
    assert record["xyz_mean3d"] == pytest.approx(1.0)  # 10 mm shift, official unit cm
    assert record["xyz_mean3d_mm"] == pytest.approx(10.0)
    assert record["xyz_al_mean3d_mm"] == pytest.approx(0.0, abs=1e-4)
    assert record["num_samples"] == 4 and record["shape_is_mano"] is True
    thresholds_cm, pck = record["pck_curves"]["xyz"]
    assert len(thresholds_cm) == len(pck) == 100 and thresholds_cm[-1] == pytest.approx(5.0)
    lines = dict(line.split(": ") for line in scores_txt.read_text().splitlines())
    assert float(lines["xyz_mean3d"]) == pytest.approx(1.0)


def test_eval_accepts_a_folder_holding_pred_json(dataset, tmp_path):
    gt, xyz, verts = dataset
    folder = tmp_path / "res"
    folder.mkdir()
    (folder / "pred.json").write_text(json.dumps([xyz.tolist(), verts.tolist()]))
    result = runner.invoke(app, ["eval", str(folder), str(gt)])
    assert result.exit_code == 0, result.output
    assert "xyz_auc3d" in result.stdout and "1.0000" in result.stdout


@pytest.mark.parametrize("content, message", [
    ("{not json", "not valid JSON"),
    ('{"xyz": []}', "expected [xyz_list, verts_list]"),
    ("[[], []]", "no samples"),
    ('[[[[0, 0]]], [[[0, 0, 0]]]]', "must have shape (N, 3)"),
    ("[[[[0, 0, NaN]]], [[[0, 0, 0]]]]", "NaN"),
    ('[[[["a", 0, 0]]], [[[0, 0, 0]]]]', "not a list of [x, y, z] numbers"),
])
def test_malformed_prediction_files_are_named(dataset, tmp_path, content, message):
    gt, _, _ = dataset
    pred = tmp_path / "pred.json"
    pred.write_text(content)
    result = runner.invoke(app, ["eval", str(pred), str(gt)])
    assert result.exit_code == 2
    assert message in result.output and str(pred) in result.output


def test_wrong_counts_and_missing_files_are_named(dataset, tmp_path):
    gt, xyz, verts = dataset
    pred = tmp_path / "pred.json"
    pred.write_text(json.dumps([xyz[:3].tolist(), verts[:3].tolist()]))
    result = runner.invoke(app, ["eval", str(pred), str(gt)])
    assert result.exit_code == 2 and "has 3 samples but the ground truth" in result.output

    pred.write_text(json.dumps([xyz[:, :20].tolist(), verts.tolist()]))
    result = runner.invoke(app, ["eval", str(pred), str(gt)])
    assert result.exit_code == 2 and "expected 21 keypoints" in result.output

    ragged = verts.tolist()
    ragged[2] = ragged[2][:10]
    pred.write_text(json.dumps([xyz.tolist(), ragged]))
    result = runner.invoke(app, ["eval", str(pred), str(gt)])
    assert result.exit_code == 2 and "sample 2 has 10 points" in result.output

    result = runner.invoke(app, ["eval", str(tmp_path / "absent.json"), str(gt)])
    assert result.exit_code == 2 and "file not found" in result.output

    result = runner.invoke(app, ["eval", str(pred), str(tmp_path / "nowhere")])
    assert result.exit_code == 2 and "not a folder" in result.output

    (gt / "evaluation_verts.json").unlink()
    result = runner.invoke(app, ["eval", str(pred), str(gt)])
    assert result.exit_code == 2 and "evaluation_verts.json: file not found" in result.output

    result = runner.invoke(app, ["eval", str(pred), str(gt), "--set", "test"])
    assert result.exit_code == 2 and "set must be one of" in result.output
