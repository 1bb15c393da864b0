"""`handloop detect IMAGE... [--box] [--left|--right] [--all] --json`: one JSON object per image; clear errors
(exit 2) naming files."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from backend.cli.main import app
from workers.capture import load_ground_truth, read_capture

runner = CliRunner()


@pytest.fixture(scope="module")
def hand_photo(rendered_capture: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """A rendered view with the most hand in it: (path, true keypoints (21, 2), hand mask)."""
    capture = read_capture(rendered_capture)
    ref = capture.sequences[0].frames[0]
    gt = load_ground_truth(ref)
    c = int(np.argmax([gt.hand_masks[cam.name].sum() for cam in capture.cameras]))
    name = capture.cameras[c].name
    return ref.image_paths[name], gt.keypoints_2d[c], gt.hand_masks[name]


def _last_json(output: str) -> list:
    return json.loads(output.strip().splitlines()[-1])


@pytest.mark.usefixtures("require_detector")
def test_detect_prints_one_object_per_image(hand_photo: tuple[Path, np.ndarray, np.ndarray]) -> None:
    path, truth, _ = hand_photo
    lo, hi = truth.min(0), truth.max(0)
    box = f"{max(lo[0] - 10, 0):.0f},{max(lo[1] - 10, 0):.0f},{hi[0] - lo[0] + 20:.0f},{hi[1] - lo[1] + 20:.0f}"
    for args, count in (([str(path), str(path)], 2), ([str(path), "--box", box], 1)):
        result = runner.invoke(app, ["detect", *args, "--json"])
        assert result.exit_code == 0, result.output
        records = _last_json(result.stdout)
        assert len(records) == count
        for record in records:
            assert set(record) == {"image", "keypoints", "scores", "presence", "side", "model_side", "right_score"}
            assert record["image"] == str(path) and record["side"] == "right"
            assert record["model_side"] in ("right", "left") and 0 <= record["right_score"] <= 1
            keypoints = np.asarray(record["keypoints"])
            assert keypoints.shape == (21, 2) and len(record["scores"]) == 21 and 0 < record["presence"] <= 1
            assert np.median(np.linalg.norm(keypoints - truth, axis=1)) < 0.2 * np.ptp(truth, axis=0).max()


def test_unreadable_and_truncated_images_name_the_file(tmp_path: Path,
                                                       hand_photo: tuple[Path, np.ndarray, np.ndarray]) -> None:
    junk = tmp_path / "junk.png"
    junk.write_text("this is no image")
    png = tmp_path / "cut.png"
    _, data = cv2.imencode(".png", np.full((64, 64, 3), 120, np.uint8))
    png.write_bytes(data.tobytes()[: len(data) // 2])
    for bad in (junk, png, tmp_path / "absent.jpg"):
        result = runner.invoke(app, ["detect", str(hand_photo[0]), str(bad), "--json"])
        assert result.exit_code == 2, result.output
        assert str(bad) in result.stderr and "[" not in result.stdout  # nothing partial printed


@pytest.mark.parametrize("box, why", [("300,10,50,50", "not inside"), ("-1,0,10,10", "not inside"),
                                      ("0,0,0,10", "positive"), ("1,2,3", "X,Y,W,H"), ("a,b,c,d", "X,Y,W,H"),
                                      ("nan,0,10,10", "finite")])
def test_a_bad_box_is_refused(box: str, why: str, hand_photo: tuple[Path, np.ndarray, np.ndarray]) -> None:
    result = runner.invoke(app, ["detect", str(hand_photo[0]), "--box", box, "--json"])
    assert result.exit_code == 2, result.output
    assert why in result.output


def test_missing_model_files_are_a_clear_error(tmp_path: Path, hand_photo: tuple[Path, np.ndarray, np.ndarray]
                                               ) -> None:
    env_code = ("import os, sys; os.environ['HANDLOOP_DETECTOR_DIR'] = sys.argv[1]; "
                "from backend.cli.main import app; app(prog_name='handloop', args=['detect', sys.argv[2], '--json'])")
    out = subprocess.run([sys.executable, "-c", env_code, str(tmp_path), str(hand_photo[0])], capture_output=True,
                         text=True)
    assert out.returncode == 2
    assert "hand_landmark_full.tflite is missing" in out.stderr and "--no-deps" in out.stderr


@pytest.mark.usefixtures("require_detector")
def test_left_flag_detects_a_mirrored_hand(tmp_path: Path, hand_photo: tuple[Path, np.ndarray, np.ndarray]) -> None:
    path, truth, _ = hand_photo
    image = cv2.imread(str(path))
    mirrored = tmp_path / "left.png"
    cv2.imwrite(str(mirrored), image[:, ::-1])
    result = runner.invoke(app, ["detect", str(mirrored), "--left", "--json"])
    assert result.exit_code == 0, result.output
    keypoints = np.asarray(_last_json(result.stdout)[0]["keypoints"])
    keypoints[:, 0] = image.shape[1] - 1 - keypoints[:, 0]
    assert np.median(np.linalg.norm(keypoints - truth, axis=1)) < 0.2 * np.ptp(truth, axis=0).max()


def test_left_and_right_together_are_refused(hand_photo: tuple[Path, np.ndarray, np.ndarray]) -> None:
    result = runner.invoke(app, ["detect", str(hand_photo[0]), "--left", "--right", "--json"])
    assert result.exit_code == 2 and "--left and --right" in result.output


@pytest.mark.usefixtures("require_detector")
def test_two_hands_each_side_on_request_and_all_listed(tmp_path: Path) -> None:
    """A rendered view with a right and a left hand (tests/support/two_hands.py, the view where both show most)."""
    from tests.support.two_hands import render_two_hands

    _, frames = render_two_hands(seed=31, frames=1)
    frame = frames[0]
    c = int(np.argmax(np.minimum(frame.visible_px["right"], frame.visible_px["left"])))
    path = tmp_path / "two.png"
    cv2.imwrite(str(path), frame.images[c][..., ::-1])
    found = {}
    for flag in ("--right", "--left"):
        result = runner.invoke(app, ["detect", str(path), flag, "--all", "--json"])
        assert result.exit_code == 0, result.output
        record = _last_json(result.stdout)[0]
        side = flag[2:]
        assert record["side"] == side and len(record["hands"]) >= 2
        assert {h["model_side"] for h in record["hands"]} <= {"right", "left"}
        found[side] = np.asarray(record["keypoints"])
        truth = frame.keypoints_2d[side][c]
        assert np.median(np.linalg.norm(found[side] - truth, axis=1)) < 0.3 * np.ptp(truth, axis=0).max()
    assert np.median(np.linalg.norm(found["right"] - found["left"], axis=1)) > 10.0
