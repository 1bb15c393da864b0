"""The calibration check's two-camera pair mode on a real recording (handpose3d: two webcams, its own calibration;
/work/shared/realdata/README.md), with keypoints the detector finds in each view WITHOUT the calibration.

The data is read from HANDLOOP_REALDATA_DIR, else ../shared/realdata beside the checkout; the test skips, saying
so, when it is absent. The calibration is converted here from the author's text files (K, distortion; R, T from
the board to each camera, in board squares, scaled by 1/20 so the rig spans ~0.6 m)."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from workers.geometry.camera import Camera
from workers.rigs.check import DETECTOR_MIN_SCORE, check_keypoints, detector_unavailable, format_report

FRAMES = np.linspace(20, 360, 10).round().astype(int)
SCALE = 1 / 20  # board squares -> about metres


def _realdata() -> Path:
    root = Path(os.environ.get("HANDLOOP_REALDATA_DIR") or Path(__file__).resolve().parents[3] / ".." / "shared"
                / "realdata") / "handpose3d"
    if not (root / "cam0_test.mp4").is_file():
        pytest.skip(f"the real recording is not here ({root}): set HANDLOOP_REALDATA_DIR to the realdata folder")
    return root


def _numbers(text: str, after: str, count: int) -> np.ndarray:
    """The first `count` numbers after the line starting with `after` in one of the author's .dat files."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip().startswith(after))
    values = " ".join(lines[start + 1:]).replace(",", " ").split()
    return np.array([float(v) for v in values[:count]])


def _camera(root: Path, k: int) -> Camera:
    intrinsic = (root / f"c{k}.dat").read_text()
    extrinsic = (root / f"rot_trans_c{k}.dat").read_text()  # the first R and T: board -> this camera
    return Camera(f"cam{k}", 720, 720, _numbers(intrinsic, "intrinsic:", 9).reshape(3, 3),
                  _numbers(intrinsic, "distortion:", 5), _numbers(extrinsic, "R:", 9).reshape(3, 3),
                  _numbers(extrinsic, "T:", 3) * SCALE)


def _frames(video: Path) -> list[np.ndarray]:
    """RGB images of FRAMES in one video."""
    capture = cv2.VideoCapture(str(video))
    images = []
    try:
        for index in FRAMES:
            capture.set(cv2.CAP_PROP_POS_FRAMES, int(index))
            ok, bgr = capture.read()
            assert ok, f"{video}: frame {index} could not be read"
            images.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    finally:
        capture.release()
    return images


def test_the_real_pair_agrees_and_a_turned_camera_does_not() -> None:
    root = _realdata()
    why = detector_unavailable()
    if why is not None:
        pytest.skip(f"the detector cannot run here: {why}")
    from workers.detector.pipeline import detect_image

    cameras = [_camera(root, 0), _camera(root, 1)]
    views = [_frames(root / f"cam{k}_test.mp4") for k in (0, 1)]
    keypoints, visible = [], []
    for f in range(len(FRAMES)):
        kp, vis = np.full((2, 21, 2), np.nan), np.zeros((2, 21), bool)
        for k in (0, 1):
            found = detect_image(views[k][f], handedness="right")  # no calibration involved
            if found is not None:
                kp[k], vis[k] = found.keypoints_px, found.scores >= DETECTOR_MIN_SCORE
        keypoints.append(kp)
        visible.append(vis)
    report = check_keypoints(cameras, keypoints, visible, source="detector")
    pair = report.pairs[0]
    assert pair.judged and pair.points >= 100, format_report(report)
    assert pair.median_px <= 5.0 and report.verdict == "pair-consistent", format_report(report)
    delta = cv2.Rodrigues(np.deg2rad(2.0) * np.array([[0.0], [1.0], [0.0]]))[0]
    turned = [cameras[0], replace(cameras[1], R=delta @ cameras[1].R, t=delta @ cameras[1].t)]
    report = check_keypoints(turned, keypoints, visible, source="detector")
    assert report.verdict == "pair-inconsistent", format_report(report)
    print(f"real pair: median {pair.median_px:.2f} px, excess {pair.excess_px:.2f} px (limit {pair.limit_px:.2f}); "
          f"turned 2 degrees: median {report.pairs[0].median_px:.2f} px, excess {report.pairs[0].excess_px:.2f} px")
