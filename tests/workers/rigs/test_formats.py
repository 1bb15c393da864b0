"""Each calibration format written from a known rig (tests/support/rig_files.py) and read back; the traps
each format invites are refused with the camera and field named."""

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


def _rigs() -> dict[str, list[Camera]]:
    return {"default": default_rig(None), "distorted": rig_files.distorted_rig()}


def _write(fmt: str, cameras: list[Camera], tmp: Path) -> tuple[Path, dict]:
    """Write `cameras` in `fmt`; returns the path and the convert() options the format needs."""
    if fmt == "anipose":
        return rig_files.write_anipose(cameras, tmp / "calibration.toml"), {}
    if fmt == "easymocap":
        return rig_files.write_easymocap(cameras, tmp / "easymocap"), {}
    if fmt == "opencv":
        return rig_files.write_opencv(cameras, tmp / "opencv"), {}
    if fmt == "panoptic":
        return rig_files.write_panoptic(cameras, tmp / "calibration_x.json"), {"camera_type": "hd"}
    if fmt == "multical":
        return rig_files.write_multical(cameras, tmp / "calibration.json"), {}
    if fmt == "jarvis":
        size = {(c.width, c.height) for c in cameras}
        return rig_files.write_jarvis(cameras, tmp / "jarvis"), {"image_size": size.pop() if len(size) == 1 else None}
    if fmt == "colmap":
        return rig_files.write_colmap(cameras, tmp / "sparse", model="FULL_OPENCV"), {}
    raise AssertionError(fmt)


def _world_from_base(cameras: list[Camera]) -> list[Camera]:
    """The rig expressed in cameras[0]'s frame (multical's world)."""
    base = cameras[0]
    return [replace(c, R=c.R @ base.R.T, t=c.t - c.R @ base.R.T @ base.t) for c in cameras]


@pytest.mark.parametrize("rig_name", ["default", "distorted"])
@pytest.mark.parametrize("fmt", ["anipose", "easymocap", "opencv", "panoptic", "multical", "colmap"])
def test_round_trip(fmt: str, rig_name: str, tmp_path: Path) -> None:
    cameras = _rigs()[rig_name]
    path, options = _write(fmt, cameras, tmp_path)
    conversion = convert(fmt, path, **options)
    expected = _world_from_base(cameras) if fmt == "multical" else cameras
    if fmt == "opencv":  # one file per camera, read in name order (cam0..cam7 is already that order)
        expected = sorted(expected, key=lambda c: c.name)
    _assert_same(conversion.cameras, expected)
    assert conversion.span_m == pytest.approx(np.sqrt(3.0), rel=1e-9)


def test_round_trip_jarvis_transposed_matlab_matrices(tmp_path: Path) -> None:
    cameras = [c for c in rig_files.distorted_rig() if (c.width, c.height) == (1280, 1024)]
    folder = rig_files.write_jarvis(cameras, tmp_path / "jarvis")
    _assert_same(convert("jarvis", folder, image_size=(1280, 1024)).cameras, cameras)
    with pytest.raises(FormatError, match=r"camera 'cam0'.*--image-size"):
        convert("jarvis", folder)


def test_multical_chained_poses_are_composed_to_the_base_camera(tmp_path: Path) -> None:
    cameras = rig_files.distorted_rig()
    path = rig_files.write_multical(cameras, tmp_path / "calibration.json", chain=True)
    conversion = convert("multical", path)
    _assert_same(conversion.cameras, _world_from_base(cameras))
    assert any("base camera 'cam0'" in note for note in conversion.notes)


def test_easymocap_names_that_look_like_numbers(tmp_path: Path) -> None:
    cameras = [replace(c, name=f"{i + 1:02d}") for i, c in enumerate(default_rig(None))]
    folder = rig_files.write_easymocap(cameras, tmp_path / "easymocap")
    _assert_same(convert("easymocap", folder).cameras, cameras)


def test_colmap_simple_models_and_pixel_origin(tmp_path: Path) -> None:
    cameras = [replace(c, dist=np.array([c.dist[0], c.dist[1], 0.0, 0.0, 0.0])) for c in default_rig(None)]
    folder = rig_files.write_colmap(cameras, tmp_path / "sparse", model="OPENCV")
    _assert_same(convert("colmap", folder).cameras, cameras)


def test_millimetres_read_as_metres_are_refused(tmp_path: Path) -> None:
    path = rig_files.write_anipose(default_rig(None), tmp_path / "calibration.toml", scale=1000.0)
    with pytest.raises(FormatError, match=r"span 1732 m.*--units mm"):
        convert("anipose", path)
    _assert_same(convert("anipose", path, unit="mm").cameras, default_rig(None), tol=1e-9)


def test_jarvis_read_in_metres_is_refused(tmp_path: Path) -> None:
    folder = rig_files.write_jarvis(default_rig(None)[:2] + default_rig(None)[4:6], tmp_path / "jarvis")
    with pytest.raises(FormatError, match=r"--units mm"):
        convert("jarvis", folder, unit="m", image_size=(1280, 1024))


def test_focal_length_in_millimetres_is_refused(tmp_path: Path) -> None:
    cameras = default_rig(None)
    K = cameras[2].K.copy()
    K[0, 0] = K[1, 1] = 4.0  # the lens's focal length in mm instead of pixels
    cameras[2] = replace(cameras[2], K=K)
    path = rig_files.write_panoptic(cameras, tmp_path / "calibration.json")
    with pytest.raises(FormatError, match=r"camera 'cam2': field 'K' focal length 4 px.*millimetres"):
        convert("panoptic", path, camera_type="hd")


def test_non_orthonormal_rotation_is_refused(tmp_path: Path) -> None:
    import json

    path = rig_files.write_panoptic(default_rig(None), tmp_path / "calibration.json")
    data = json.loads(path.read_text())
    data["cameras"][5]["R"][0][0] *= 1.01
    path.write_text(json.dumps(data))
    with pytest.raises(FormatError, match=r"camera 'cam5': field 'R' is not orthonormal"):
        convert("panoptic", path, camera_type="hd")


def test_reflection_is_refused(tmp_path: Path) -> None:
    import json

    path = rig_files.write_panoptic(default_rig(None), tmp_path / "calibration.json")
    data = json.loads(path.read_text())
    data["cameras"][1]["R"][2] = [-v for v in data["cameras"][1]["R"][2]]
    path.write_text(json.dumps(data))
    with pytest.raises(FormatError, match=r"camera 'cam1': field 'R' has determinant -1"):
        convert("panoptic", path, camera_type="hd")


def test_camera_to_world_pose_read_as_world_to_camera_is_refused(tmp_path: Path) -> None:
    cameras = default_rig(None)
    # R and t of camera -> world (R^T, the camera centre): the camera looks away from the rig.
    cameras[4] = replace(cameras[4], R=cameras[4].R.T, t=cameras[4].center_world)
    path = rig_files.write_anipose(cameras, tmp_path / "calibration.toml")
    with pytest.raises(FormatError, match=r"camera 'cam4': the point the other cameras look at is .* behind it"):
        convert("anipose", path)
    assert len(convert("anipose", path, check_geometry=False).cameras) == 8


def test_camera_count_mismatch_is_refused(tmp_path: Path) -> None:
    folder = rig_files.write_easymocap(default_rig(None), tmp_path / "easymocap", drop_extri="cam6")
    with pytest.raises(FormatError, match=r"lists 7 cameras .* lists 8 .*camera count mismatch"):
        convert("easymocap", folder)
    path = rig_files.write_anipose(default_rig(None), tmp_path / "calibration.toml")
    with pytest.raises(FormatError, match=r"8 cameras .* expected 10: camera count mismatch"):
        convert("anipose", path, expect_cameras=10)


def test_multical_missing_pose_is_a_count_mismatch(tmp_path: Path) -> None:
    import json

    path = rig_files.write_multical(default_rig(None), tmp_path / "calibration.json")
    data = json.loads(path.read_text())
    del data["camera_poses"]["cam3_to_cam0"]
    path.write_text(json.dumps(data))
    with pytest.raises(FormatError, match=r"no pose for camera\(s\) \['cam3'\].*camera count mismatch"):
        convert("multical", path)


@pytest.mark.parametrize(("fmt", "message"), [
    ("anipose", r"camera 'cam3': distortion model 'fisheye' is not supported"),
    ("opencv", r"camera 'cam3': distortion model 'rational' \(k4 non-zero\) is not supported"),
    ("multical", r"camera 'cam0': distortion model 'thin_prism' is not supported"),
    ("colmap", r"camera 'cam0'.*distortion model 'OPENCV_FISHEYE' is not supported"),
])
def test_unsupported_distortion_models_are_named(fmt: str, message: str, tmp_path: Path) -> None:
    cameras = default_rig(None)
    if fmt == "anipose":
        path = rig_files.write_anipose(cameras, tmp_path / "c.toml", fisheye="cam3")
    elif fmt == "opencv":
        path = rig_files.write_opencv(cameras, tmp_path / "opencv", rational="cam3")
    elif fmt == "multical":
        path = rig_files.write_multical(cameras, tmp_path / "c.json", model="thin_prism")
    else:
        path = rig_files.write_colmap(cameras, tmp_path / "sparse", model="OPENCV_FISHEYE")
    with pytest.raises(FormatError, match=message):
        convert(fmt, path)


def test_malformed_files_name_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "calibration.toml"
    bad.write_text("[cam_0\nname = 'x'")
    with pytest.raises(FormatError, match=r"calibration.toml: not valid TOML"):
        convert("anipose", bad)
    (tmp_path / "c.json").write_text('{"cameras": [{"name": "a"}]}')
    with pytest.raises(FormatError, match=r"cameras\[0\]: missing field"):
        convert("panoptic", tmp_path / "c.json")
    with pytest.raises(FormatError, match=r"file not found"):
        convert("easymocap", tmp_path / "nowhere")
    with pytest.raises(FormatError, match=r"unknown calibration format 'bogus'"):
        convert("bogus", bad)
    good = rig_files.write_anipose(default_rig(None), tmp_path / "good.toml")
    good.write_text(good.read_text().replace("distortions = [", "distortions = 5\nx = [", 1))
    with pytest.raises(FormatError, match=r"camera 'cam0': field 'dist' has 1 coefficients"):
        convert("anipose", good)
    good.write_text(good.read_text().replace("distortions = 5", 'distortions = "none"', 1))
    with pytest.raises(FormatError, match=r"camera 'cam0': field 'distortions' is not a list of numbers"):
        convert("anipose", good)


def test_non_finite_numbers_are_refused(tmp_path: Path) -> None:
    path = rig_files.write_anipose(default_rig(None), tmp_path / "calibration.toml")
    text = path.read_text().splitlines()
    i = next(n for n, line in enumerate(text) if line.startswith("translation"))
    text[i] = "translation = [nan, 0.0, 1.0]"
    path.write_text("\n".join(text))
    with pytest.raises(FormatError, match=r"camera 'cam0': field 'translation' contains non-finite"):
        convert("anipose", path)


def test_centimetres_are_read_with_units_cm(tmp_path: Path) -> None:
    path = rig_files.write_anipose(default_rig(None), tmp_path / "calibration.toml", scale=100.0)
    with pytest.raises(FormatError,
                       match=r"span 173.2 m, .*--units cm \(a 1.73 m rig, cameras 0.864..0.868 m from its centre\)"):
        convert("anipose", path)
    _assert_same(convert("anipose", path, unit="cm").cameras, default_rig(None), tol=1e-9)
