"""`handloop calibration convert`: writes a loadable calibration, refuses with exit code 2 and writes nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from backend.cli.main import app
from tests.support import rig_files
from workers.geometry.camera import load_calibration
from workers.geometry.rig import default_rig


def test_convert_writes_calibration(tmp_path: Path) -> None:
    src = rig_files.write_jarvis(default_rig(None)[:2], tmp_path / "jarvis")
    out = tmp_path / "out" / "calibration.json"
    result = CliRunner().invoke(app, ["calibration", "convert", "--from", "jarvis", str(src), "--image-size",
                                      "1280x1024", "--out", str(out)])
    assert result.exit_code == 0, result.output
    cameras = load_calibration(out)
    np.testing.assert_allclose(cameras[1].t, default_rig(None)[1].t, atol=1e-9)
    assert "read in mm" in result.output


def test_convert_refuses_and_writes_nothing(tmp_path: Path) -> None:
    src = rig_files.write_anipose(default_rig(None), tmp_path / "calibration.toml", scale=1000.0)
    out = tmp_path / "calibration.json"
    result = CliRunner().invoke(app, ["calibration", "convert", "--from", "anipose", str(src), "--out", str(out)])
    assert result.exit_code == 2
    assert "--units mm" in result.output
    assert not out.exists() and list(tmp_path.iterdir()) == [src]


def test_convert_bad_options(tmp_path: Path) -> None:
    src = rig_files.write_anipose(default_rig(None), tmp_path / "calibration.toml")
    runner = CliRunner()
    result = runner.invoke(app, ["calibration", "convert", "--from", "kalibr", str(src), "--out", "x.json"])
    assert result.exit_code == 2 and "--from must be one of" in result.output
    result = runner.invoke(app, ["calibration", "convert", "--from", "jarvis", str(src), "--image-size", "big",
                                 "--out", "x.json"])
    assert result.exit_code == 2 and "--image-size must look like" in result.output
    (tmp_path / "exists.json").write_text("{}")
    result = runner.invoke(app, ["calibration", "convert", "--from", "anipose", str(src), "--out",
                                 str(tmp_path / "exists.json")])
    assert result.exit_code == 2 and "pass --force" in result.output
    assert (tmp_path / "exists.json").read_text() == "{}"
