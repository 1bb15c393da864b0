"""The real two-webcam recording (TemugeB/handpose3d), calibrated in board squares of unknown size: converting it
as metres is refused, the detected hand's size gives the board square's size, and with it the rig converts to a
plausible size and the detector's lift works. Skipped when the recording is absent."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from backend.cli.main import app
from tests.support import rig_files
from tests.support.handpose3d_rig import handpose3d_cameras, handpose3d_dir
from workers.geometry.camera import Camera, load_calibration
from workers.rigs.formats import anipose
from workers.rigs.hand_scale import ADULT_HAND_LENGTH_M, estimate_hand_scale, triangulate_keypoints

FRAMES = (40, 100, 160, 220, 280, 340)


def _detections(folder: Path):
    """Per camera, per frame of FRAMES, the detector's ViewKeypoints (or None)."""
    from workers.detector import detector_status
    from workers.detector.pipeline import detect_image

    if detector_status() is not None:
        pytest.skip(f"the detector is unavailable: {detector_status()}")
    views = []
    for c in range(2):
        capture = cv2.VideoCapture(str(folder / f"cam{c}_test.mp4"))
        row = []
        for frame in FRAMES:
            capture.set(cv2.CAP_PROP_POS_FRAMES, frame)
            ok, bgr = capture.read()
            assert ok, f"cam{c}_test.mp4 frame {frame}"
            row.append(detect_image(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), handedness="right"))
        capture.release()
        views.append(row)
    return views


def test_the_hand_gives_the_board_squares_size(tmp_path: Path) -> None:
    from workers.detector.lifting import lift
    from workers.tasks.preannotate import _scale_problem

    folder = handpose3d_dir()
    src = rig_files.write_anipose(handpose3d_cameras(folder), tmp_path / "calibration.toml")
    out = tmp_path / "calibration.json"
    runner = CliRunner()
    refused = runner.invoke(app, ["calibration", "convert", "--from", "anipose", str(src), "--out", str(out)])
    assert refused.exit_code == 2 and "--scale METRES_PER_FILE_UNIT" in refused.output, refused.output

    # The file's cameras in its own unit (board squares), as the reader gives them.
    raws, _ = anipose.read(src)
    board = [Camera(r.name, r.width, r.height, r.K, r.dist, r.R, r.t) for r in raws]
    views = _detections(folder)
    assert sum(v is not None for row in views for v in row) >= 10, "the detector should find the hand"
    pixels = np.full((2, len(FRAMES), 21, 2), np.nan)
    for c, row in enumerate(views):
        for f, view in enumerate(row):
            if view is not None:
                pixels[c, f] = view.keypoints_px
    size = estimate_hand_scale(triangulate_keypoints(pixels, board))
    print(f"\nhandpose3d: {size.message('board squares')}")
    assert size.verdict == "too large" and size.factor == pytest.approx(0.048, abs=0.002)  # docs/calibration.md
    assert ADULT_HAND_LENGTH_M[0] <= size.hand_length * size.factor <= ADULT_HAND_LENGTH_M[1]

    result = runner.invoke(app, ["calibration", "convert", "--from", "anipose", str(src), "--out", str(out),
                                 "--scale", f"{size.factor:.6g}"])
    assert result.exit_code == 0, result.output
    span = float(re.search(r"rig span ([0-9.]+) m", result.output).group(1))
    print(f"handpose3d: --scale {size.factor:.4g} -> rig span {span} m")
    assert 0.3 <= span <= 1.0 and span == pytest.approx(0.598, abs=0.025)  # docs/calibration.md
    distances = re.search(r"cam0 ([0-9.]+) m, cam1 ([0-9.]+) m", result.output).groups()
    assert [float(d) for d in distances] == pytest.approx([0.72, 0.82], abs=0.04)
    metric = load_calibration(out)
    for f in range(len(FRAMES)):
        frame_views = [views[0][f], views[1][f]]
        if any(v is None for v in frame_views):
            continue
        # In board squares the lift (metric thresholds) fails and pre-annotation says why; scaled, it works.
        wrong = lift(frame_views, board)
        assert np.isfinite(wrong.points_world).all(axis=1).sum() < 6
        assert "the calibration's scale looks wrong, the hand is too large by" in _scale_problem(wrong, board)
        right = lift(frame_views, metric)
        assert np.isfinite(right.points_world).all(axis=1).sum() >= 15
        assert _scale_problem(right, metric) == ""
