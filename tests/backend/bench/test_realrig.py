"""`handloop bench realrig` on the real two-webcam recording (issue 36; skipped, saying so, when the recording is
absent): its board-unit calibration converted as read, the wrong scale flagged by the calibration check with the
factor that gives an adult hand, the rig converted again with it, the videos assembled and pre-annotated as round 0
does: the hand found and fitted in >= 95 % of frames, the two views' keypoints epipolar-consistent (median <= 5 px),
the fit's residual to the detector keypoints <= 1 % of the image width at the median."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from backend.cli.main import app
from tests.support.handpose3d_rig import handpose3d_dir


@pytest.mark.slow
@pytest.mark.usefixtures("require_detector")
def test_a_labs_first_hour_on_the_real_recording_meets_the_issues_targets() -> None:
    handpose3d_dir()
    # Every 10th frame: 38 frames, as many as the hand needs to be judged (frame 0 has the hand outside cam0).
    result = CliRunner().invoke(app, ["bench", "realrig", "--every", "10", "--json"])
    assert result.exit_code == 0, result.output[-3000:]
    record = json.loads(result.stdout.strip().splitlines()[-1])
    print(json.dumps({k: v for k, v in record.items() if k not in ("machine", "settings")}))
    assert record["scale_flagged"] and record["rig_span_as_read_m"] > 10, record
    assert record["targets_met"] == {name: True for name in record["targets"]}, record
    assert 0.3 <= record["rig_span_scaled_m"] <= 1.0, record
    assert record["check_verdict"] == "pair-consistent", record
