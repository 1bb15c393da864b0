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
