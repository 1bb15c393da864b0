"""caliscope and Pose2Sim calibration TOMLs written from a known rig and read back; a file read with the wrong
`--from` names the format it looks like."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.support import rig_files
from workers.geometry.camera import Camera
from workers.geometry.rig import default_rig
from workers.rigs.formats import FormatError, convert


def _assert_same(read: list[Camera], expected: list[Camera], tol: float = 1e-9) -> None:
    assert [c.name for c in read] == [c.name for c in expected]
    for a, b in zip(read, expected, strict=True):
        assert (a.width, a.height) == (b.width, b.height), a.name
        for key in ("K", "dist", "R", "t"):
            np.testing.assert_allclose(getattr(a, key), getattr(b, key), rtol=0, atol=tol, err_msg=f"{a.name} {key}")


def _caliscope_named(cameras: list[Camera]) -> list[Camera]:
    """caliscope stores no names: camera i reads back as cam_i."""
    return [replace(c, name=f"cam_{i}") for i, c in enumerate(cameras)]


@pytest.mark.parametrize("layout,matrix_rotation", [("camera_array", False), ("camera_array", True),
                                                     ("config", True), ("config", False)])
def test_caliscope_round_trip(layout: str, matrix_rotation: bool, tmp_path: Path) -> None:
    cameras = rig_files.distorted_rig()
    path = rig_files.write_caliscope(cameras, tmp_path / f"{layout}.toml", layout=layout,
                                     matrix_rotation=matrix_rotation)
    conversion = convert("caliscope", path)
    _assert_same(conversion.cameras, _caliscope_named(cameras))
    assert conversion.span_m == pytest.approx(np.sqrt(3.0), rel=1e-9)


def test_caliscope_ignored_camera_is_left_out_and_an_unposed_one_refused(tmp_path: Path) -> None:
    cameras = default_rig(None)
    path = rig_files.write_caliscope(cameras, tmp_path / "camera_array.toml", ignore="cam2")
    conversion = convert("caliscope", path)
    _assert_same(conversion.cameras, [c for c in _caliscope_named(cameras) if c.name != "cam_2"])
    assert any("'cam_2': ignore = true" in n for n in conversion.notes)
    path = rig_files.write_caliscope(cameras, tmp_path / "camera_array.toml", unposed="cam5")
    with pytest.raises(FormatError, match=r"camera 'cam_5': no 'rotation' or 'translation': caliscope never posed"):
        convert("caliscope", path)


def test_pose2sim_round_trip(tmp_path: Path) -> None:
    cameras = [replace(c, name=f"cam_{i + 1:02d}", dist=np.r_[c.dist[:4], 0.0])
               for i, c in enumerate(rig_files.distorted_rig())]
    path = rig_files.write_pose2sim(cameras, tmp_path / "Calib_board.toml")
    assert "size = [ 2048.0," in path.read_text() or "size = [ 1280.0," in path.read_text()
    _assert_same(convert("pose2sim", path).cameras, cameras)
    _assert_same(convert("anipose", path).cameras, cameras)  # the same layout: no mismatch


@pytest.mark.parametrize("write,fmt,message", [
    (lambda c, p: rig_files.write_caliscope(c, p / "camera_array.toml"), "anipose",
     r"camera_array.toml: this looks like a caliscope camera_array.toml, not anipose's layout: use --from "
     r"caliscope \(read as anipose: \[cameras\]: missing field\(s\) \['name'"),
    (lambda c, p: rig_files.write_caliscope(c, p / "config.toml", layout="config"), "pose2sim",
     r"this looks like a caliscope config.toml, not pose2sim's layout: use --from caliscope"),
    (lambda c, p: rig_files.write_anipose(c, p / "calibration.toml"), "caliscope",
     r"this looks like an Anipose / Pose2Sim calibration.toml, not caliscope's layout: use --from anipose"),
    (lambda c, p: rig_files.write_panoptic(c, p / "calibration_x.json"), "multical",
     r"this looks like a CMU Panoptic calibration JSON, not multical's layout: use --from panoptic"),
    (lambda c, p: rig_files.write_easymocap(c, p / "em"), "colmap",
     r"this looks like an EasyMocap intri.yml / extri.yml folder, not colmap's layout: use --from easymocap"),
])
def test_a_file_of_another_format_is_named(write, fmt: str, message: str, tmp_path: Path) -> None:
    path = write(default_rig(None), tmp_path)
    with pytest.raises(FormatError, match=message):
        convert(fmt, path)


def test_an_unrecognised_file_keeps_the_readers_message(tmp_path: Path) -> None:
    path = tmp_path / "calibration.toml"
    path.write_text('[cam_0]\nname = "cam0"\n')
    with pytest.raises(FormatError, match=r"\[cam_0\]: missing field\(s\) \['size', 'matrix'") as info:
        convert("anipose", path)
    assert "looks like" not in str(info.value)


def test_anipose_reads_a_rotation_matrix_too(tmp_path: Path) -> None:
    cameras = default_rig(None)
    path = rig_files.write_anipose(cameras, tmp_path / "calibration.toml")
    lines = path.read_text().splitlines()
    rotations = iter(cameras)
    path.write_text("\n".join(f"rotation = {next(rotations).R.tolist()}" if line.startswith("rotation = ") else line
                              for line in lines))
    _assert_same(convert("anipose", path).cameras, cameras)
