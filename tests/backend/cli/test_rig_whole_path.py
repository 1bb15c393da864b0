"""Bring your own rig, the whole path: a synthetic rig written as another toolchain's calibration (Anipose,
millimetres) -> `handloop calibration convert` -> `handloop capture assemble` from per-camera image folders
(green screen keyed) -> import -> a fit on the imported rig whose projections land on the synthetic keypoints."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from backend.cli.main import app
from backend.models.enums import Role
from tests.support import rig_files
from workers.capture import load_frame_masks, load_ground_truth, read_capture


def test_convert_assemble_import_fit(sqlite_env, tmp_path: Path) -> None:
    from workers.fitting.config import FitConfig
    from workers.fitting.engine import FittingEngine
    from workers.fitting.inputs import FrameObservations
    from workers.geometry.projection import project_points
    from workers.handmodel.builtin import build_builtin_hand
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig
    from workers.tasks.inputs import load_rig

    synth = tmp_path / "synth"
    generate_capture(synth, SynthConfig(num_sequences=1, frames_per_sequence=2, seed=5, width_px=320), workers=1)
    truth = read_capture(synth)
    seq = truth.sequences[0]
    assert seq.green_screen
    # What a lab brings: its toolchain's calibration (millimetres) and one image folder per camera.
    toml = rig_files.write_anipose(list(truth.cameras), tmp_path / "calibration.toml", scale=1000.0)
    for frame in seq.frames:
        for cam, path in frame.image_paths.items():
            (tmp_path / "frames" / cam).mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, tmp_path / "frames" / cam / f"frame{frame.index}.jpg")

    runner = CliRunner()
    result = runner.invoke(app, ["calibration", "convert", "--from", "anipose", str(toml), "--units", "mm",
                                 "--out", str(tmp_path / "calibration.json")])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["capture", "assemble", "--calibration", str(tmp_path / "calibration.json"),
                                 "--images", str(tmp_path / "frames"), "--green-screen", "--fps", "30",
                                 "--out", str(tmp_path / "capture"), "--workers", "2"])
    assert result.exit_code == 0, result.output
    assembled = read_capture(tmp_path / "capture")
    for a, b in zip(assembled.cameras, truth.cameras, strict=True):
        np.testing.assert_allclose(a.t, b.t, atol=1e-9)
        np.testing.assert_allclose(a.R, b.R, atol=1e-9)
    # the keyed masks agree with the synthetic pipeline's chroma key
    for got_frame, true_frame in zip(assembled.sequences[0].frames, seq.frames, strict=True):
        got, want = load_frame_masks(got_frame), load_frame_masks(true_frame)
        for cam in want:
            iou = (got[cam] & want[cam]).sum() / max((got[cam] | want[cam]).sum(), 1)
            assert iou > 0.9, (cam, iou)  # measured 0.94-0.98

    response = sqlite_env.client.post("/api/admin/imports", headers=sqlite_env.headers(Role.admin),
                                      json={"path": str(tmp_path / "capture"), "project": "byo-rig"})
    assert response.status_code == 201, response.text
    with sqlite_env.session() as session:
        rig = load_rig(session, response.json()["project_id"])
    cameras = list(rig.cameras)
    assert [c.name for c in cameras] == list(truth.camera_names)

    gts = [load_ground_truth(f) for f in seq.frames]
    frames = [FrameObservations(np.where(gt.visibility[..., None], gt.keypoints_2d, np.nan),
                                gt.visibility.astype(float)) for gt in gts]
    results = FittingEngine(build_builtin_hand(), cameras, FitConfig()).fit(frames)
    for gt, fit in zip(gts, results, strict=True):
        projected, _ = project_points(fit.keypoints, cameras)
        error = np.linalg.norm(projected - gt.keypoints_2d, axis=2)[gt.visibility]
        # measured: median 0.21 px, p90 0.38 px, 0.8-0.9 mm
        assert np.median(error) < 1.0 and np.percentile(error, 90) < 2.0, (np.median(error), error.max())
        assert 1000 * np.linalg.norm(fit.keypoints - gt.keypoints_3d, axis=1).mean() < 4.0
