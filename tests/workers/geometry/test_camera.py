"""Camera validation and the calibration file format."""

from __future__ import annotations

import json

import numpy as np
import pytest

from workers.geometry.camera import CalibrationError, load_calibration, save_calibration
from workers.geometry.rig import default_rig


def test_round_trip(tmp_path):
    rig = default_rig()
    save_calibration(rig, tmp_path / "calibration.json")
    loaded = load_calibration(tmp_path / "calibration.json")
    for a, b in zip(rig, loaded, strict=True):
        assert a.name == b.name and (a.width, a.height) == (b.width, b.height)
        for key in ("K", "dist", "R", "t"):
            assert np.array_equal(getattr(a, key), getattr(b, key))


def _write(tmp_path, cameras):
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({"cameras": cameras}))
    return path


@pytest.mark.parametrize(("mutate", "message"), [
    (lambda c: c.pop("K"), r"cameras\[0\]: missing field\(s\) \['K'\]"),
    (lambda c: c.update(lens="4mm"), r"cameras\[0\]: unknown field\(s\) \['lens'\]"),
    (lambda c: c.update(t=[0, 0, "x"]), r"field 't' is not numeric"),
    (lambda c: c.update(t=[0, 0, float("nan")]), r"field 't' contains non-finite numbers"),
    (lambda c: c.update(dist=[0, 0, 0, 0]), r"field 'dist' must have shape \(5,\)"),
    (lambda c: c.update(R=np.diag([1, 1, -1]).tolist()), r"field 'R' is not a rotation matrix"),
    (lambda c: c.update(width=0), r"field 'width' must be an integer"),
    (lambda c: c.update(height=2.5), r"field 'height' must be an integer"),
])
def test_bad_camera_fields_are_named(tmp_path, mutate, message):
    camera = default_rig()[0].to_dict()
    mutate(camera)
    with pytest.raises(CalibrationError, match=message):
        load_calibration(_write(tmp_path, [camera]))


def test_bad_files(tmp_path):
    with pytest.raises(CalibrationError, match="file not found"):
        load_calibration(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(CalibrationError, match="not valid JSON"):
        load_calibration(tmp_path / "bad.json")
    cam = default_rig()[0].to_dict()
    with pytest.raises(CalibrationError, match="names are not unique"):
        load_calibration(_write(tmp_path, [cam, cam]))
    with pytest.raises(CalibrationError, match="'cameras' is empty"):
        load_calibration(_write(tmp_path, []))


def test_scaling_keeps_rays():
    """A pixel scaled to another resolution sees the same ray (pixel-centre convention)."""
    cam = default_rig(width_px=None)[3]
    small = cam.scaled(320)
    assert small.width == 320 and small.height == 256
    u, v = 100.0, 700.0
    s = 320 / cam.width
    ray_full = np.linalg.solve(cam.K, [u, v, 1])
    ray_small = np.linalg.solve(small.K, [s * (u + 0.5) - 0.5, s * (v + 0.5) - 0.5, 1])
    assert np.allclose(ray_full, ray_small)


def test_a_resize_scales_each_axis_and_a_rendered_size_keeps_square_pixels():
    """Where the height rounds (1280x1024 at 100 px: 80.0; at 90 px: 72.0; at 97 px: 77.6 -> 78), a resized
    image stretches y by 78 / 1024, so the resized camera's fy does too; a synthetic rig rendered at that
    size keeps fx = fy (the export's FreiHAND K assumes the renderer's camera)."""
    cam = default_rig(width_px=None)[3]
    resized, rendered = cam.scaled(97), cam.scaled(97, square_pixels=True)
    assert resized.height == rendered.height == 78
    assert resized.K[1, 1] == pytest.approx(cam.K[1, 1] * 78 / 1024)
    assert resized.K[1, 2] == pytest.approx(78 / 1024 * (cam.K[1, 2] + 0.5) - 0.5)
    assert rendered.K[1, 1] == pytest.approx(rendered.K[0, 0]) and rendered.K[0, 0] == pytest.approx(resized.K[0, 0])
    assert all(c.K[0, 0] == pytest.approx(c.K[1, 1]) for c in default_rig(width_px=97))


def test_default_rig_matches_the_paper():
    rig = default_rig(width_px=None)
    assert len(rig) == 8
    sizes = sorted((c.width, c.height) for c in rig)
    assert sizes.count((800, 600)) == 2 and sizes.count((1280, 1024)) == 6
    focal_mm = sorted({round(c.K[0, 0] * 0.0048, 3) for c in rig})
    assert focal_mm == [4.0, 6.0]
    centers = np.stack([c.center_world for c in rig])
    assert np.allclose(np.abs(centers), 0.5)  # the corners of a 1 m cube around the origin
    assert len({tuple(np.sign(c)) for c in centers}) == 8
    for cam in rig:  # each looks at the centre (within the aiming jitter)
        origin_cam = cam.R @ np.zeros(3) + cam.t
        assert origin_cam[2] > 0.8
        assert np.hypot(*origin_cam[:2]) / origin_cam[2] < 0.1
