"""The calibration check flags the camera whose calibration disagrees, and only that one (exact keypoints; the
detector-like noise and the blame rates are in test_check_rates.py)."""

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
from tests.support.hand_views import hand_track
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
from workers.detector.types import ViewKeypoints
from workers.geometry.camera import Camera, save_calibration
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.rigs.check import CheckError, check_capture, check_keypoints, format_report

FRAMES = 6


def _keypoints(rng: np.random.Generator) -> np.ndarray:
    """(21, 3) an adult-sized hand, turned at random, near the rig centre, metres (the check also judges the rig's
    scale by the hand's size)."""
    return hand_track(rng, frames=1, reach_m=0.1)[0]


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
        # each view a flat colour naming its frame and camera: the detector fakes below recognise it at any size
        write_frame(root, "seq000", i, {c.name: np.full((c.height, c.width, 3), (i, k, 7), np.uint8)
                                        for k, c in enumerate(cameras)}, image_format="png", ground_truth=gt)
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
    assert report.flagged == [] and report.verdict == "consistent" and report.agrees
    assert all(c.epipolar_px < 0.01 and c.judged and c.partners == 7 for c in report.cameras)
    assert all(p.median_px < 0.01 and p.consistent for p in report.pairs) and len(report.pairs) == 28


@pytest.mark.parametrize("unit", [20.0, 0.01])
def test_a_wrong_unit_is_flagged_with_the_factor_that_makes_the_hand_adult(capture: Path, unit: float) -> None:
    """Board squares read as metres (x20) or metres read as centimetres (x0.01): every pixel check still agrees (the
    geometry is the same up to scale), but the triangulated hand is of no human size: the report says so, with the
    factor, and the command would exit 1."""
    cameras = read_capture(capture).cameras
    _recalibrate(capture, [replace(c, t=c.t * unit) for c in cameras])
    report = check_capture(capture)
    assert report.verdict == "consistent" and report.scale_wrong and not report.agrees
    assert report.hand_scale.factor == pytest.approx(1 / unit, rel=0.15)
    assert report.hand_scale.verdict == ("too large" if unit > 1 else "too small")
    record = report.to_dict()
    assert record["hand_scale"]["scale_wrong"] is True and "looks wrong" in record["hand_scale"]["message"]
    assert "SCALE: " in format_report(report)
    _recalibrate(capture, list(cameras))
    assert not check_capture(capture).scale_wrong


@pytest.mark.parametrize("bad", [0, 3, 6])
def test_two_degrees_off_flags_that_camera_only(capture: Path, bad: int) -> None:
    cameras = default_rig(320)
    cameras[bad] = _rotated(cameras[bad], 2.0)
    _recalibrate(capture, cameras)
    report = check_capture(capture)
    assert report.flagged == [f"cam{bad}"] and report.verdict == "camera", report.to_dict()
    assert f"camera 'cam{bad}'" in report.summary
    correction = report.cameras[bad].correction
    assert correction["kind"] == "rotation" and abs(correction["degrees"] - 2.0) < 0.05, correction
    assert "turned by 2.0 degrees" in report.cameras[bad].reason and f"camera 'cam{bad}'" in report.cameras[bad].reason


def test_swapped_names_and_transposed_rotation_are_flagged(capture: Path) -> None:
    cameras = default_rig(320)
    swapped = list(cameras)
    swapped[1], swapped[5] = replace(cameras[5], name="cam1"), replace(cameras[1], name="cam5")
    _recalibrate(capture, swapped)
    report = check_capture(capture)
    assert sorted(report.flagged) == ["cam1", "cam5"] and report.verdict == "swapped", report.summary
    assert report.cameras[1].correction["with"] == "cam5"
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
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1, result.stdout  # exactly one line of JSON on stdout
    data = json.loads(lines[-1])
    assert data["flagged"] == ["cam4"] and len(data["cameras"]) == 8 and data["verdict"] == "camera"
    assert data["cameras"][4]["correction"]["kind"] == "rotation"


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
    with pytest.raises(CheckError, match=r"at least 2, the rig has 1"):
        check_keypoints(cameras[:1], [np.zeros((1, 21, 2))], [np.ones((1, 21), bool)])
    rng = np.random.default_rng(1)
    px = [project_points(_keypoints(rng), cameras)[0] for _ in range(3)]
    visible = [np.ones((8, 21), bool) for _ in px]
    for v in visible:
        v[7, 1:] = False  # cam7 sees one keypoint a frame
    report = check_keypoints(cameras, px, visible)
    assert report.flagged == [] and not report.cameras[7].judged
    assert any("'cam7': not judged, too few keypoints: it shares 3" in n for n in report.notes), report.notes
    text = format_report(report)
    assert "nan" not in text.lower() and "cam7" in text and "not judged" in text


def test_a_camera_with_one_partner_is_not_judged_for_that_reason() -> None:
    """cam2 shares keypoints with cam0 only: not enough partners, said so (not 'too few keypoints')."""
    cameras = default_rig(320)[:4]
    rng = np.random.default_rng(2)
    px = [project_points(_keypoints(rng), cameras)[0] for _ in range(3)]
    visible = [np.ones((4, 21), bool) for _ in px]
    for v in visible:
        v[2, :10] = False  # cam2 sees keypoints 10-20 ...
        v[1, 10:] = v[3, 10:] = False  # ... which cam1 and cam3 do not
    report = check_keypoints(cameras, px, visible)
    note = next(n for n in report.notes if "'cam2'" in n)
    assert "too few partner cameras" in note and "with 1 camera " in note, note
    assert report.cameras[2].partners == 1 and report.verdict == "consistent"


def test_a_disagreeing_pair_with_an_unjudged_camera_blames_nobody() -> None:
    """cam3 (turned) shares keypoints with cam0 only: their pair disagrees, but cam3 cannot be judged, so cam0 is
    not blamed for it: the verdict says both explain it."""
    cameras = default_rig(320)[:4]
    rng = np.random.default_rng(4)
    px = [project_points(_keypoints(rng), cameras)[0] for _ in range(FRAMES)]
    visible = [np.ones((4, 21), bool) for _ in px]
    for v in visible:
        v[3, :10] = False
        v[1, 10:] = v[2, 10:] = False
    turned = list(cameras)
    turned[3] = _rotated(cameras[3], 2.0)
    report = check_keypoints(turned, px, visible)
    assert report.flagged == [] and report.verdict == "ambiguous" and not report.agrees, report.summary
    assert "cam3 has too few partner cameras" in report.summary


def test_two_cameras_judge_the_pair_only() -> None:
    cameras = default_rig(320)[:2]
    rng = np.random.default_rng(3)
    px = [project_points(_keypoints(rng), cameras)[0] for _ in range(FRAMES)]
    visible = [np.ones((2, 21), bool) for _ in px]
    report = check_keypoints(cameras, px, visible)
    assert report.verdict == "pair-consistent" and report.flagged == [] and report.agrees
    assert "only the pair" in report.summary
    turned = [cameras[0], _rotated(cameras[1], 2.0)]
    report = check_keypoints(turned, px, visible)
    assert report.verdict == "pair-inconsistent" and report.flagged == [] and not report.agrees
    assert report.pairs[0].excess_px > report.pairs[0].limit_px
    text = format_report(report)
    assert "nan" not in text.lower() and "disagrees" in text


def test_pose_chained_to_another_camera_read_as_world_is_flagged(capture: Path) -> None:
    cameras = default_rig(320)
    base, cam = cameras[0], cameras[5]
    R_rel = cam.R @ base.R.T  # cam5's pose in cam0's frame (multical-style), taken for a world pose
    cameras[5] = replace(cam, R=R_rel, t=cam.t - R_rel @ base.t)
    _recalibrate(capture, cameras)
    report = check_capture(capture)
    assert report.flagged == ["cam5"]
    assert "camera 'cam5'" in report.cameras[5].reason


class ImageDetector:
    """Stands in for workers.detector.pipeline.detect_image: recognises the view by its flat colour (frame i,
    camera k) and answers the keypoints of the TRUE rig at the image's size; `calls` records every call."""

    def __init__(self, capture: Path, true_cameras: list[Camera]) -> None:
        self.frames = list(read_capture(capture).sequences[0].frames)
        self.true = true_cameras
        self.calls: list[tuple] = []

    def __call__(self, image, box_px=None, *, handedness="right"):
        frame, k = int(image[0, 0, 0]), int(image[0, 0, 1])
        self.calls.append((frame, k, image.shape, handedness))
        points = load_ground_truth(self.frames[frame]).keypoints_3d
        px, _ = project_points(points, [self.true[k].scaled(image.shape[1])])
        return ViewKeypoints(px[0], np.full(21, 0.9), 0.99, handedness, np.zeros(4), 0.0)


def _install_detector(monkeypatch, detect_image) -> None:
    """workers.detector.pipeline replaced, for this test, by a module whose `detect_image` is the one given
    (the check imports it when it runs) and whose detector is always available."""
    fake = types.ModuleType("workers.detector.pipeline")
    fake.detect_image = detect_image
    fake.detector_status = lambda: None
    monkeypatch.setitem(sys.modules, "workers.detector.pipeline", fake)
    monkeypatch.setattr(workers.detector, "pipeline", fake, raising=False)


def test_detector_keypoints_go_through_the_same_check(capture: Path, monkeypatch) -> None:
    """The detector path: every view detected on its own (no calibration), each once, then the same check."""
    detector = ImageDetector(capture, default_rig(320))
    _install_detector(monkeypatch, detector)
    cameras = default_rig(320)
    cameras[2] = _rotated(cameras[2], 2.0)
    _recalibrate(capture, cameras)
    report = check_capture(capture, source="detector")
    assert report.source == "detector" and report.frames == FRAMES and report.flagged == ["cam2"]
    assert sorted((f, k) for f, k, _, _ in detector.calls) == [(f, k) for f in range(FRAMES) for k in range(8)]
    assert all(h == "right" for *_, h in detector.calls)
    assert check_capture(capture).source == "ground-truth"  # auto prefers ground truth


def test_the_detector_reads_the_working_width_and_its_keypoints_come_back_in_full_pixels(tmp_path: Path,
                                                                                       monkeypatch) -> None:
    """A capture with a working width: the detector is given the views at that width; the check works in full
    pixels (exactly: the pairs agree to 1e-6 px) and still flags a camera 2 degrees off."""
    full = default_rig(320)
    _write_capture(tmp_path / "cap", full, working_width_px=128)
    detector = ImageDetector(tmp_path / "cap", full)
    _install_detector(monkeypatch, detector)
    report = check_capture(tmp_path / "cap", source="detector")
    small = [c.scaled(128) for c in full]
    assert len(detector.calls) == FRAMES * 8
    assert all(shape == (small[k].height, small[k].width, 3) for _, k, shape, _ in detector.calls)
    assert report.flagged == [] and max(p.median_px for p in report.pairs) < 1e-6  # full pixels, exactly
    cameras = default_rig(320)
    cameras[6] = _rotated(cameras[6], 2.0)
    _recalibrate(tmp_path / "cap", cameras)
    assert check_capture(tmp_path / "cap", source="detector").flagged == ["cam6"]


def test_two_camera_capture_says_so_before_detecting_and_one_camera_is_refused(tmp_path: Path,
                                                                                monkeypatch) -> None:
    rig = default_rig(320)[:2]
    _write_capture(tmp_path / "two", rig)
    events: list[str] = []
    detector = ImageDetector(tmp_path / "two", rig)

    def recording(image, box_px=None, *, handedness="right"):
        events.append("detect")
        return detector(image, box_px, handedness=handedness)

    _install_detector(monkeypatch, recording)
    report = check_capture(tmp_path / "two", source="detector", log=events.append)
    assert "only the pair's agreement can be judged" in events[0] and events[1:] == ["detect"] * (FRAMES * 2)
    assert report.verdict == "pair-consistent" and report.flagged == []
    result = CliRunner().invoke(app, ["calibration", "check", str(tmp_path / "two"), "--keypoints", "detector"])
    assert result.exit_code == 0 and "the pair cam0-cam1 agrees" in result.stdout, result.output

    _write_capture(tmp_path / "one", default_rig(320)[:1])
    events.clear()
    result = CliRunner().invoke(app, ["calibration", "check", str(tmp_path / "one"), "--keypoints", "detector"])
    assert result.exit_code == 2 and "at least 2, the capture has 1" in result.output, result.output
    assert events == []  # refused before any detection
