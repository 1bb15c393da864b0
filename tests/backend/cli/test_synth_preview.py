"""`handloop synth`, `handloop preview` and `handloop bench synth` through the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from backend.cli.main import app
from workers.capture import load_ground_truth, read_capture

runner = CliRunner()


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "cap"
    result = runner.invoke(app, ["synth", "--out", str(out), "--sequences", "2", "--frames", "3", "--seed", "0",
                                 "--width", "96", "--workers", "2"])
    assert result.exit_code == 0, result.output
    assert "wrote 6 frames x 8 views" in result.stdout
    return out


def test_synth_writes_a_capture_the_reader_loads(capture):
    cap = read_capture(capture)
    assert cap.synthetic and len(cap.cameras) == 8 and cap.cameras[0].width == 96
    train, evaluation = cap.sequences
    assert (train.split, train.green_screen, train.has_masks) == ("train", True, True)
    assert (evaluation.split, evaluation.green_screen, evaluation.has_masks) == ("evaluation", False, False)
    assert evaluation.holds_object and evaluation.object_kind in ("ball", "cylinder", "box")
    gt = load_ground_truth(evaluation.frames[2], cap.hand_model.num_vertices)
    assert gt.keypoints_2d.shape == (8, 21, 2) and gt.visibility.shape == (8, 21)
    assert set(gt.hand_masks) == set(cap.camera_names)


def test_same_seed_same_capture(capture, tmp_path):
    out = tmp_path / "again"
    result = runner.invoke(app, ["synth", "--out", str(out), "--sequences", "2", "--frames", "3", "--seed", "0",
                                 "--width", "96", "--workers", "1"])
    assert result.exit_code == 0, result.output
    for rel in ("sequences/seq001/ground_truth/000002.npz", "sequences/seq000/masks/cam3/000001.png"):
        a, b = capture / rel, out / rel
        if rel.endswith(".npz"):
            with np.load(a) as x, np.load(b) as y:
                np.testing.assert_array_equal(x["keypoints_2d"], y["keypoints_2d"])
        else:
            assert a.read_bytes() == b.read_bytes()


def test_synth_refuses_a_non_empty_folder_unless_forced(tmp_path):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "thesis.txt").write_text("precious")
    args = ["synth", "--out", str(out), "--sequences", "1", "--frames", "1", "--width", "64", "--workers", "1"]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "not empty" in result.output and "--force" in result.output
    result = runner.invoke(app, [*args, "--force"])  # not a capture: still refused
    assert result.exit_code == 2 and "refusing to delete" in result.output
    assert (out / "thesis.txt").read_text() == "precious"
    (out / "thesis.txt").unlink()
    assert runner.invoke(app, args).exit_code == 0
    assert runner.invoke(app, args).exit_code == 2
    assert runner.invoke(app, [*args, "--force"]).exit_code == 0


@pytest.mark.parametrize("bad", [["--sequences", "0"], ["--frames", "-1"], ["--width", "8"], ["--workers", "-2"]])
def test_synth_bad_arguments(tmp_path, bad):
    result = runner.invoke(app, ["synth", "--out", str(tmp_path / "x"), *bad])
    assert result.exit_code == 2 and "Invalid value" in result.output


def test_preview_draws_eight_views_with_keypoints(capture, tmp_path):
    out = tmp_path / "x.png"
    result = runner.invoke(app, ["preview", str(capture), "--frame", "0", "--full", "--out", str(out)])
    assert result.exit_code == 0, result.output
    grid = cv2.imread(str(out))
    assert grid.shape[1] == 4 * 480 and grid.shape[0] >= 2 * 360
    # The skeleton's finger colours are drawn (pure-ish yellow of the index finger, not in a green screen).
    b, g, r = (grid[..., i].astype(int) for i in range(3))
    assert ((r > 200) & (g > 150) & (b < 60)).sum() > 20
    masks = tmp_path / "m.png"
    result = runner.invoke(app, ["preview", str(capture), "--frame", "2", "--sequence", "seq001", "--masks",
                                 "--out", str(masks)])
    assert result.exit_code == 0 and masks.is_file()
    zoomed = tmp_path / "z.png"
    result = runner.invoke(app, ["preview", str(capture), "--zoom", "--tile-width", "200", "--out", str(zoomed)])
    assert result.exit_code == 0 and cv2.imread(str(zoomed)).shape[1] == 4 * 200


@pytest.mark.parametrize(("args", "message"), [
    (["--frame", "7"], "frames 0..2"),
    (["--sequence", "nope"], "no sequence 'nope'"),
])
def test_preview_errors(capture, tmp_path, args, message):
    result = runner.invoke(app, ["preview", str(capture), *args, "--out", str(tmp_path / "x.png")])
    assert result.exit_code == 2 and message in result.output


def test_preview_of_a_broken_capture_names_the_file(capture, tmp_path):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(capture, broken)
    shutil.rmtree(broken / "sequences/seq000/images/cam5")
    result = runner.invoke(app, ["preview", str(broken), "--out", str(tmp_path / "x.png")])
    assert result.exit_code == 2 and "images" in result.output and "cam5" in result.output


def test_bench_synth_prints_json_last(monkeypatch):
    import backend.bench.synth as bench

    monkeypatch.setattr(bench, "SIZES", {True: (1, 2), False: (1, 2)})
    result = runner.invoke(app, ["bench", "synth", "--json", "--quick", "--width", "64", "--workers", "1"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout.strip().splitlines()[-1])
    assert record["frames_per_s"] > 0 and record["frames"] == 2
    assert {"commit", "machine", "settings"} <= set(record) and record["settings"]["width_px"] == 64
