"""The calibration check flags the camera whose calibration disagrees, and only that one."""

from __future__ import annotations

import json
import sys
import types
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import workers.detector
from backend.cli.main import app
from workers.capture import (
    GroundTruth,
    HandModelInfo,
    Subject,
    load_ground_truth,
    read_capture,
    write_capture_header,
    write_frame,
    write_sequence,
)
from workers.detector.types import LiftedKeypoints, ViewKeypoints
from workers.geometry.camera import Camera, save_calibration
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.rigs.check import CheckError, check_capture, check_keypoints

FRAMES = 6


def _keypoints(rng: np.random.Generator) -> np.ndarray:
    """(21, 3) a hand-sized cloud near the rig centre, metres."""
    return rng.normal(0.0, 0.04, 3) + rng.normal(0.0, 0.05, (21, 3))


def _write_capture(root: Path, cameras: list[Camera], seed: int = 0, working_width_px: int | None = None
                   ) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    write_capture_header(root, "check", cameras, [Subject("s0")], HandModelInfo("test", is_mano=False),
                         synthetic=True, working_width_px=working_width_px)
    names = [c.name for c in cameras]
    write_sequence(root, "seq000", subject_id="s0", split="train", green_screen=False, fps=10.0, num_frames=FRAMES,
                   holds_object=False, camera_names=names, image_format="png", with_ground_truth=True)
    all_px = []
    for i in range(FRAMES):
        points = _keypoints(rng)
        px, _ = project_points(points, cameras)
        all_px.append(px)
        gt = GroundTruth(betas=np.zeros(10), pose=np.zeros(45), global_orient=np.zeros(3), transl=np.zeros(3),
                         keypoints_3d=points, vertices=np.zeros((4, 3)), keypoints_2d=px,
                         visibility=np.ones((len(cameras), 21), bool), camera_names=tuple(names),
                         hand_masks={c.name: np.zeros((c.height, c.width), bool) for c in cameras})
        write_frame(root, "seq000", i, {c.name: np.zeros((c.height, c.width, 3), np.uint8) for c in cameras},
                    image_format="png", ground_truth=gt)
    return all_px


def _rotated(cam: Camera, degrees: float, axis=(0.0, 1.0, 0.0)) -> Camera:
    """The camera turned by `degrees` about an axis of its own frame (a stale extrinsic)."""
    delta = cv2.Rodrigues(np.deg2rad(degrees) * np.asarray(axis, float).reshape(3, 1))[0]
    return replace(cam, R=delta @ cam.R, t=delta @ cam.t)


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    _write_capture(tmp_path / "cap", default_rig(320))
    return tmp_path / "cap"


def _recalibrate(capture: Path, cameras: list[Camera]) -> None:
    save_calibration(cameras, capture / "calibration.json")


def test_true_calibration_flags_nothing(capture: Path) -> None:
    report = check_capture(capture)
    assert report.source == "ground-truth" and report.frames == FRAMES
    assert report.flagged == []
    assert all(c.reprojection_px < 0.01 for c in report.cameras)
    assert all(p.median_px < 0.01 for p in report.pairs) and len(report.pairs) == 28


@pytest.mark.parametrize("bad", [0, 3, 6])
def test_two_degrees_off_flags_that_camera_only(capture: Path, bad: int) -> None:
    cameras = default_rig(320)
    cameras[bad] = _rotated(cameras[bad], 2.0)
    _recalibrate(capture, cameras)
    report = check_capture(capture)
    assert report.flagged == [f"cam{bad}"], report.to_dict()
    figure = report.cameras[bad]
    assert f"camera 'cam{bad}'" in figure.reason
    others = [c for c in report.cameras if c.name != f"cam{bad}"]
    assert max(c.reprojection_px for c in others) < figure.reprojection_px / 3


def test_swapped_names_and_transposed_rotation_are_flagged(capture: Path) -> None:
    cameras = default_rig(320)
    swapped = list(cameras)
    swapped[1], swapped[5] = replace(cameras[5], name="cam1"), replace(cameras[1], name="cam5")
    _recalibrate(capture, swapped)
    assert sorted(check_capture(capture).flagged) == ["cam1", "cam5"]
    transposed = list(cameras)
    transposed[2] = replace(cameras[2], R=cameras[2].R.T)  # camera -> world rotation read as world -> camera
    _recalibrate(capture, transposed)
    assert check_capture(capture).flagged == ["cam2"]


def test_cli_prints_and_exits_1_on_a_flag(capture: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["calibration", "check", str(capture)])
    assert result.exit_code == 0, result.output
    assert "no camera disagrees" in result.output
    cameras = default_rig(320)
    cameras[4] = _rotated(cameras[4], 2.0, axis=(1.0, 0.0, 0.0))
    _recalibrate(capture, cameras)
    result = runner.invoke(app, ["calibration", "check", str(capture), "--json"])
    assert result.exit_code == 1
    data = json.loads(result.stdout)
    assert data["flagged"] == ["cam4"] and len(data["cameras"]) == 8


def test_without_ground_truth_or_detector_the_check_says_why(tmp_path: Path) -> None:
    cameras = default_rig(64)[:3]
    write_capture_header(tmp_path, "real", cameras, [Subject("s0")], HandModelInfo("m", is_mano=False),
                         synthetic=False)
    write_sequence(tmp_path, "seq000", subject_id="s0", split="evaluation", green_screen=False, fps=10.0,
                   num_frames=1, holds_object=False, camera_names=[c.name for c in cameras], image_format="png")
    write_frame(tmp_path, "seq000", 0, {c.name: np.zeros((c.height, c.width, 3), np.uint8) for c in cameras},
                image_format="png")
    from workers.rigs.check import detector_unavailable

    why = detector_unavailable()
    if why is None:
        pytest.skip("the detector is installed here: the fallback message is not reached")
    with pytest.raises(CheckError, match=r"the detector cannot run: .*ground truth"):
        check_capture(tmp_path)
    with pytest.raises(CheckError, match=r"has no ground truth"):
        check_capture(tmp_path, source="ground-truth")


def test_too_few_cameras_or_points() -> None:
    cameras = default_rig(64)
    with pytest.raises(CheckError, match=r"at least 3 cameras"):
        check_keypoints(cameras[:2], [np.zeros((2, 21, 2))], [np.ones((2, 21), bool)])
    points = np.random.default_rng(1).normal(0, 0.05, (21, 3))
    px, _ = project_points(points, cameras)
    visible = np.ones((8, 21), bool)
    visible[7, 3:] = False  # cam7 sees only three keypoints
    report = check_keypoints(cameras, [px], [visible])
    assert report.flagged == [] and any("'cam7': only 3 usable keypoints" in n for n in report.notes)


def test_pose_chained_to_another_camera_read_as_world_is_flagged(capture: Path) -> None:
    cameras = default_rig(320)
    base, cam = cameras[0], cameras[5]
    R_rel = cam.R @ base.R.T  # cam5's pose in cam0's frame (multical-style), taken for a world pose
    cameras[5] = replace(cam, R=R_rel, t=cam.t - R_rel @ base.t)
    _recalibrate(capture, cameras)
    report = check_capture(capture)
    assert report.flagged == ["cam5"]
    assert "camera 'cam5'" in report.cameras[5].reason


def _install_detector(monkeypatch, detect_frame) -> None:
    """workers.detector.pipeline replaced, for this test, by a module whose `detect_frame` is the one given
    (the check imports it when it runs) and whose detector is always available."""
    fake = types.ModuleType("workers.detector.pipeline")
    fake.detect_frame = detect_frame
    fake.detector_status = lambda: None
    monkeypatch.setitem(sys.modules, "workers.detector.pipeline", fake)
    monkeypatch.setattr(workers.detector, "pipeline", fake, raising=False)


def test_detector_keypoints_go_through_the_same_check(capture: Path, monkeypatch) -> None:
    """The detector path, with workers.detector.pipeline replaced by one that returns the ground truth's
    keypoints as its views (the interface of workers/detector/types.py)."""
    frames = list(read_capture(capture).sequences[0].frames)
    calls = []

    def detect_frame(images, cameras, masks=None, *, handedness="right"):
        gt = load_ground_truth(frames[len(calls)])
        calls.append((len(images), len(cameras), masks, handedness))
        views = tuple(ViewKeypoints(gt.keypoints_2d[c], np.where(gt.visibility[c], 0.9, 0.1), 0.99, handedness,
                                    np.zeros(4), 0.0) for c in range(len(cameras)))
        return LiftedKeypoints(gt.keypoints_3d, np.ones(21), np.ones((21, len(cameras)), bool), np.zeros(21), views)

    _install_detector(monkeypatch, detect_frame)
    cameras = default_rig(320)
    cameras[2] = _rotated(cameras[2], 2.0)
    _recalibrate(capture, cameras)
    report = check_capture(capture, source="detector")
    assert report.source == "detector" and report.frames == FRAMES and report.flagged == ["cam2"]
    assert calls[0] == (8, 8, None, "right") and len(calls) == FRAMES
    assert check_capture(capture).source == "ground-truth"  # auto prefers ground truth


def test_the_detector_reads_the_working_width_and_its_keypoints_come_back_in_full_pixels(tmp_path: Path,
                                                                                       monkeypatch) -> None:
    """A capture with a working width: the detector is given the views at that width with the cameras scaled
    alike (it answers with the truth projected by the true cameras at that width); the check works in full
    pixels and still flags a camera 2 degrees off."""
    full = default_rig(320)
    _write_capture(tmp_path / "cap", full, working_width_px=128)
    frames = list(read_capture(tmp_path / "cap").sequences[0].frames)
    seen = []

    def detect_frame(images, cameras, masks=None, *, handedness="right"):
        gt = load_ground_truth(frames[len(seen)])
        seen.append(([im.shape for im in images], [(c.width, c.height) for c in cameras]))
        px, _ = project_points(gt.keypoints_3d, [c.scaled(128) for c in full])  # the true rig, at 128 px
        views = tuple(ViewKeypoints(px[c], np.full(21, 0.9), 0.99, handedness, np.zeros(4), 0.0)
                      for c in range(len(cameras)))
        return LiftedKeypoints(gt.keypoints_3d, np.ones(21), np.ones((21, len(cameras)), bool), np.zeros(21), views)

    _install_detector(monkeypatch, detect_frame)
    report = check_capture(tmp_path / "cap", source="detector")
    small = [c.scaled(128) for c in full]
    assert len(seen) == FRAMES and all(s == ([(c.height, c.width, 3) for c in small],
                                             [(c.width, c.height) for c in small]) for s in seen)
    assert report.flagged == [] and max(c.reprojection_px for c in report.cameras) < 1e-6  # full pixels, exactly
    cameras = default_rig(320)
    cameras[6] = _rotated(cameras[6], 2.0)
    _recalibrate(tmp_path / "cap", cameras)
    seen.clear()
    assert check_capture(tmp_path / "cap", source="detector").flagged == ["cam6"]
