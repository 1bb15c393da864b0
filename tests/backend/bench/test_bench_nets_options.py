"""`handloop bench nets` refuses bad choices (--mvnet, the configurations, the frame count) before it synthesises
or trains anything."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from backend.cli.main import app

runner = CliRunner()


@pytest.mark.parametrize(("args", "says"), [
    (["--mvnet", "mediapipe"], "paper, detector, both"),
    (["--detector-config", "nope"], "unknown configuration 'nope'"),
    (["--detector-config", "cpu-small"], "is not detector-backed"),
    (["--config", "nope", "--mvnet", "paper"], "unknown configuration 'nope'"),
])
def test_bad_choices_are_refused(args, says, tmp_path):
    result = runner.invoke(app, ["bench", "nets", "--quick", "--data", str(tmp_path), *args])
    assert result.exit_code == 2, result.output
    assert says in " ".join(result.output.split())
    assert not any(tmp_path.iterdir())  # nothing written


def test_run_refuses_an_unknown_choice(tmp_path):
    from backend.bench.nets import run

    with pytest.raises(ValueError, match="mvnet must be one of"):
        run(quick=True, data_dir=tmp_path, mvnet="all")
    with pytest.raises(ValueError, match="frames_per_sequence"):
        run(quick=True, data_dir=tmp_path, frames_per_sequence=0)
    assert not any(tmp_path.iterdir())


def test_mvnet_steps_must_be_positive(tmp_path):
    from backend.bench.nets import run

    result = runner.invoke(app, ["bench", "nets", "--quick", "--data", str(tmp_path), "--mvnet-steps", "0"])
    assert result.exit_code == 2 and "--mvnet-steps" in result.output
    with pytest.raises(ValueError, match="mvnet_steps must be >= 1"):
        run(quick=True, data_dir=tmp_path, mvnet_steps=0)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(("args", "says"), [
    (["--steps", "100,x"], "not a comma-separated list"),
    (["--steps", "0"], "must be positive"),
    (["--config", "nope"], "unknown configuration 'nope'"),
    (["--config", "cpu-small"], "is not detector-backed"),
    (["--sequences", "3"], "--sequences"),
    (["--config", "cpu-small-detector:nofield=1"], "nofield=1"),
    (["--config", "cpu-small-detector:detector_residual=bogus"], "detector_residual must be"),
    (["--config", "cpu-small-detector:detector_offsets=maybe"], "detector_offsets must be true or false"),
])
def test_mvnet_precision_refuses_bad_input(args, says, tmp_path):
    result = runner.invoke(app, ["bench", "mvnet-precision", "--data", str(tmp_path), *args])
    assert result.exit_code == 2, result.output
    assert says in " ".join(result.output.split())
    assert not any(tmp_path.iterdir())


def test_mvnet_precision_run_refuses_bad_input(tmp_path):
    from backend.bench.mvnet_precision import run

    for kwargs, says in (({"configs": ["cpu-small"]}, "not detector-backed"), ({"steps": []}, "positive step"),
                         ({"configs": ["nope"]}, "unknown configuration"), ({"frames": 2}, "frames must be")):
        with pytest.raises(ValueError, match=says):
            run(data_dir=tmp_path, **kwargs)
    assert not any(tmp_path.iterdir())


def test_mvnet_precision_overrides_and_confidence_ranking():
    import numpy as np

    from backend.bench.mvnet_precision import confidence_ranking, parse_config

    config = parse_config("cpu-small-detector:detector_residual=likelihood,detector_sigma_px=0.8")
    assert config.mvnet.detector_residual == "likelihood" and config.mvnet.detector_sigma_px == 0.8
    assert parse_config("cpu-small-detector").mvnet.detector_offsets is True  # the default
    assert parse_config("cpu-small-detector").mvnet.detector_pose_correction is True  # the default
    assert parse_config("cpu-small-detector:detector_pose_correction=false").mvnet.detector_pose_correction is False
    without = parse_config("cpu-small-detector:detector_offsets=False,detector_pose_correction=False").mvnet
    assert without.detector_offsets is False and without.detector_pose_correction is False
    with pytest.raises(ValueError, match="detector_pose_correction needs detector_offsets"):
        parse_config("cpu-small-detector:detector_offsets=False")
    errors = np.array([[2.0] * 21, [5.0] * 21, [20.0] * 21, [30.0] * 21])
    ranked = confidence_ranking(np.array([[0.9] * 21, [0.8] * 21, [0.5] * 21, [0.4] * 21]), errors)
    assert ranked["spearman_frame"] == -1.0 and ranked["spearman_keypoint"] < -0.9
    assert ranked["confidence_max_le_10mm"] == 0.85 and ranked["frames_max_le_10mm"] == 2
    assert ranked["confidence_max_gt_10mm"] == 0.45 and ranked["frames_max_gt_10mm"] == 2
    inverted = confidence_ranking(np.array([[0.4] * 21, [0.5] * 21, [0.8] * 21, [0.9] * 21]), errors)
    assert inverted["spearman_frame"] == 1.0
