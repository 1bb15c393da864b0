"""Bring your own rig, the whole path, for each calibration format: a synthetic rig written as that toolchain's
calibration (in its usual unit; Anipose in millimetres, the unit trap) -> `handloop calibration convert` ->
`handloop capture assemble` from per-camera image folders (green screen keyed) -> import -> a fit on the
imported rig whose projections land on the synthetic keypoints."""

from __future__ import annotations

import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from backend.cli.main import app
from backend.models.enums import Role
from tests.support import rig_files
from workers.capture import load_frame_masks, load_ground_truth, read_capture


@pytest.fixture(scope="module")
def synth(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    root = tmp_path_factory.mktemp("rig-whole-path") / "synth"
    generate_capture(root, SynthConfig(num_sequences=1, frames_per_sequence=2, seed=5, width_px=320), workers=1)
    return root


def _write(fmt: str, cameras: list, tmp_path: Path) -> tuple[Path, list[str]]:
    """The rig in `fmt`; returns the path and the convert options it needs."""
    if fmt == "anipose":
        return rig_files.write_anipose(cameras, tmp_path / "calibration.toml", scale=1000.0), ["--units", "mm"]
    if fmt == "easymocap":
        return rig_files.write_easymocap(cameras, tmp_path / "easymocap"), []
    if fmt == "opencv":
        return rig_files.write_opencv(cameras, tmp_path / "opencv"), []
    if fmt == "panoptic":
        return rig_files.write_panoptic(cameras, tmp_path / "calibration_x.json"), ["--camera-type", "hd"]
    if fmt == "multical":
        return rig_files.write_multical(cameras, tmp_path / "calibration.json"), []
    if fmt == "jarvis":
        (size,) = {(c.width, c.height) for c in cameras}
        return rig_files.write_jarvis(cameras, tmp_path / "jarvis"), ["--image-size", f"{size[0]}x{size[1]}"]
    return rig_files.write_colmap(cameras, tmp_path / "sparse", model="FULL_OPENCV"), []


@pytest.mark.parametrize("fmt", ["anipose", "easymocap", "opencv", "panoptic", "multical", "jarvis", "colmap"])
def test_convert_assemble_import_fit(fmt: str, synth: Path, sqlite_env, tmp_path: Path) -> None:
    from workers.fitting.config import FitConfig
    from workers.fitting.engine import FittingEngine
    from workers.fitting.inputs import FrameObservations
    from workers.geometry.projection import project_points
    from workers.handmodel.builtin import build_builtin_hand
    from workers.tasks.inputs import load_rig

    truth = read_capture(synth)
    seq = truth.sequences[0]
    assert seq.green_screen
    cameras = list(truth.cameras)
    if fmt == "jarvis":  # one image size per file set (MATLAB's files do not store it): the rig's commonest
        size = Counter((c.width, c.height) for c in cameras).most_common(1)[0][0]
        cameras = [c for c in cameras if (c.width, c.height) == size]
    names = [c.name for c in cameras]
    # What a lab brings: its toolchain's calibration and one image folder per camera.
    source, options = _write(fmt, cameras, tmp_path)
    for frame in seq.frames:
        for cam in names:
            (tmp_path / "frames" / cam).mkdir(parents=True, exist_ok=True)
            shutil.copyfile(frame.image_paths[cam], tmp_path / "frames" / cam / f"frame{frame.index}.jpg")

    runner = CliRunner()
    result = runner.invoke(app, ["calibration", "convert", "--from", fmt, str(source), *options,
                                 "--out", str(tmp_path / "handloop-calibration.json")])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["capture", "assemble", "--calibration", str(tmp_path / "handloop-calibration.json"),
                                 "--images", str(tmp_path / "frames"), "--green-screen", "--fps", "30",
                                 "--out", str(tmp_path / "capture"), "--workers", "2"])
    assert result.exit_code == 0, result.output
    assembled = read_capture(tmp_path / "capture")
    # multical's world is its first camera's frame: the rig, and the truth, expressed there
    base = cameras[0]
    R_w, t_w = (base.R, base.t) if fmt == "multical" else (np.eye(3), np.zeros(3))
    expected = {c.name: c for c in cameras}
    assert sorted(c.name for c in assembled.cameras) == sorted(names)
    for a in assembled.cameras:
        b = expected[a.name]
        np.testing.assert_allclose(a.R, b.R @ R_w.T, atol=1e-9)
        np.testing.assert_allclose(a.t, b.t - b.R @ R_w.T @ t_w, atol=1e-9)
        np.testing.assert_allclose(a.K, b.K, atol=1e-9)
    # the keyed masks agree with the synthetic pipeline's chroma key
    for got_frame, true_frame in zip(assembled.sequences[0].frames, seq.frames, strict=True):
        got, want = load_frame_masks(got_frame), load_frame_masks(true_frame)
        for cam in names:
            iou = (got[cam] & want[cam]).sum() / max((got[cam] | want[cam]).sum(), 1)
            assert iou > 0.9, (cam, iou)  # measured 0.94-0.98

    response = sqlite_env.client.post("/api/admin/imports", headers=sqlite_env.headers(Role.admin),
                                      json={"path": str(tmp_path / "capture"), "project": f"byo-{fmt}"})
    assert response.status_code == 201, response.text
    with sqlite_env.session() as session:
        rig = list(load_rig(session, response.json()["project_id"]).cameras)
    assert [c.name for c in rig] == [c.name for c in assembled.cameras]

    columns = [list(truth.camera_names).index(c.name) for c in rig]
    gts = [load_ground_truth(f) for f in seq.frames]
    frames = [FrameObservations(np.where(gt.visibility[columns, :, None], gt.keypoints_2d[columns], np.nan),
                                gt.visibility[columns].astype(float)) for gt in gts]
    results = FittingEngine(build_builtin_hand(), rig, FitConfig()).fit(frames)
    for gt, fit in zip(gts, results, strict=True):
        projected, _ = project_points(fit.keypoints, rig)
        visible = gt.visibility[columns]
        error = np.linalg.norm(projected - gt.keypoints_2d[columns], axis=2)[visible]
        # measured (Anipose, 8 cameras): median 0.21 px, p90 0.38 px, 0.8-0.9 mm
        assert np.median(error) < 1.0 and np.percentile(error, 90) < 2.0, (np.median(error), error.max())
        keypoints_world = gt.keypoints_3d @ R_w.T + t_w
        assert 1000 * np.linalg.norm(fit.keypoints - keypoints_world, axis=1).mean() < 5.0
