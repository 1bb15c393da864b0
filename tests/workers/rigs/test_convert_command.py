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


def _focus_distances(cameras) -> list[float]:
    """Each camera's distance to the least-squares meeting point of the optical axes (computed here, not by
    workers.rigs)."""
    rows, rhs = [], []
    for cam in cameras:
        c, d = -cam.R.T @ cam.t, cam.R[2]
        P = np.eye(3) - np.outer(d, d)
        rows.append(P)
        rhs.append(P @ c)
    focus = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]
    return [float(np.linalg.norm(-cam.R.T @ cam.t - focus)) for cam in cameras]


def _convert(src: Path, out: Path, *args: str):
    return CliRunner().invoke(app, ["calibration", "convert", "--from", "anipose", str(src), "--out", str(out), *args])


def test_inches_print_the_span_and_each_cameras_distance_to_the_rigs_centre(tmp_path: Path) -> None:
    rig = default_rig(None)
    src = rig_files.write_anipose(rig, tmp_path / "calibration.toml", scale=1 / 0.0254)
    result = _convert(src, tmp_path / "calibration.json", "--units", "in")
    assert result.exit_code == 0, result.output
    np.testing.assert_allclose(load_calibration(tmp_path / "calibration.json")[3].t, rig[3].t, atol=1e-9)
    span = max(np.linalg.norm(a.center_world - b.center_world) for a in rig for b in rig)
    assert f"read in in, rig span {span:.3f} m" in result.output
    distances = ", ".join(f"{c.name} {d:.3f} m" for c, d in zip(rig, _focus_distances(rig), strict=True))
    assert f"camera distance to the rig's centre (the common focus of the optical axes): {distances}\n" in result.output


def test_board_squares_need_scale_and_the_hint_proposes_only_plausible_units(tmp_path: Path) -> None:
    rig = default_rig(None)  # cameras 0.87 m from the centre; the file in 4.4 cm board squares
    src = rig_files.write_anipose(rig, tmp_path / "calibration.toml", scale=1 / 0.044)
    out = tmp_path / "calibration.json"
    for args in ([], ["--units", "cm"]):
        result = _convert(src, out, *args)
        assert result.exit_code == 2 and not out.exists(), result.output
        hint = result.output.replace("\n", " ")
        assert "for a hand-capture rig: the length unit is wrong" in hint
        assert f"--units in (a {np.sqrt(3) * 0.0254 / 0.044:.3g} m rig" in hint
        assert "--units cm" not in hint.split("pass", 1)[1]
        assert "--units mm" not in hint and "--scale METRES_PER_FILE_UNIT" in hint
    result = _convert(src, out, "--scale", "0.044")
    assert result.exit_code == 0, result.output
    assert "read in --scale 0.044 m per file unit, rig span 1.732 m" in result.output
    np.testing.assert_allclose(load_calibration(out)[5].t, rig[5].t, atol=1e-9)


def test_an_unknown_unit_converts_as_read_with_a_note_naming_the_check(tmp_path: Path) -> None:
    rig = default_rig(None)
    src = rig_files.write_anipose(rig, tmp_path / "calibration.toml", scale=1 / 0.044)  # 4.4 cm board squares
    out = tmp_path / "calibration.json"
    refused = _convert(src, out)
    assert refused.exit_code == 2 and "--unknown-scale" in refused.output.replace("\n", " ")
    result = _convert(src, out, "--unknown-scale")
    assert result.exit_code == 0, result.output
    note = result.output.replace("\n", " ")
    assert "the unit is unknown (--unknown-scale): read in m" in note and "calibration check CAPTURE" in note
    np.testing.assert_allclose(load_calibration(out)[5].t, rig[5].t / 0.044, atol=1e-9)  # as read, unscaled


def test_no_unit_fits_so_only_scale_is_proposed(tmp_path: Path) -> None:
    src = rig_files.write_anipose(default_rig(None), tmp_path / "calibration.toml", scale=0.1)  # 10 m units
    result = _convert(src, tmp_path / "calibration.json")
    assert result.exit_code == 2
    assert "no unit (m, cm, mm, in) gives a plausible rig: pass --scale" in result.output.replace("\n", " ")


def test_units_and_scale_are_exclusive_and_scale_is_positive(tmp_path: Path) -> None:
    src = rig_files.write_anipose(default_rig(None), tmp_path / "calibration.toml")
    out = tmp_path / "calibration.json"
    result = _convert(src, out, "--units", "m", "--scale", "1")
    assert result.exit_code == 2 and "give --units or --scale, not both" in result.output
    result = _convert(src, out, "--scale", "0")
    assert result.exit_code == 2 and "--scale must be a positive number" in result.output
    result = _convert(src, out, "--units", "ft")
    assert result.exit_code == 2 and "--units must be one of m, cm, mm, in" in result.output
    assert not out.exists()


def test_a_stereo_pair_with_near_parallel_axes_is_measured_from_its_centroid(tmp_path: Path) -> None:
    """Axes 2 degrees apart meet 2.9 m in front by chance (toed in or out by calibration noise): no focus to judge
    the distances by."""
    from dataclasses import replace

    import cv2

    left = default_rig(None)[0]
    turn = cv2.Rodrigues(np.array([0.0, np.radians(2.0), 0.0]))[0]
    right = replace(left, name="cam1", R=turn @ left.R, t=turn @ left.t + np.array([-0.1, 0.0, 0.0]))
    src = rig_files.write_anipose([left, right], tmp_path / "calibration.toml")
    result = _convert(src, tmp_path / "calibration.json", "--no-geometry-check")
    assert result.exit_code == 0, result.output
    assert "rig span 0.100 m" in result.output
    assert "(the centroid of the cameras): cam0 0.050 m, cam1 0.050 m" in result.output
