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
