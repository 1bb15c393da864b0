"""The FreiHAND writer on records made straight from a synthetic capture (no server): parameters map to
FreiHAND's convention and back, composites keep the hand, wrong hand models are refused, and a failing
export writes nothing."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from workers.capture import load_ground_truth, read_capture
from workers.export.freihand import (
    ExportError,
    ExportOptions,
    freihand_theta,
    mesh_from_freihand,
    read_freihand_set,
    write_freihand,
)
from workers.export.records import SampleRecord, ViewRecord
from workers.handmodel.loading import load_hand_model
from workers.handmodel.params import HandParams
from workers.handmodel.posed import posed_mesh


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    out = tmp_path_factory.mktemp("writer-capture") / "cap"
    generate_capture(out, SynthConfig(num_sequences=1, frames_per_sequence=2, seed=7, width_px=96), workers=1)
    return read_capture(out)


def records_of(capture, model_file: str = "handloop-builtin v1") -> list[SampleRecord]:
    out = []
    for seq in capture.sequences:
        for frame in seq.frames:
            gt = load_ground_truth(frame)
            views = tuple(ViewRecord(name=c.name, width=c.width, height=c.height, K=c.K, dist=c.dist, R=c.R, t=c.t,
                                     image_key=str(frame.image_paths[c.name]),
                                     foreground_mask_key=str(frame.mask_paths[c.name])) for c in capture.cameras)
            out.append(SampleRecord(
                sample_id=len(out) + 1, fit_id=len(out) + 1, sequence=seq.id, frame_index=frame.index,
                split=seq.split, green_screen=seq.green_screen, round_index=0, stream="annotated",
                params=np.concatenate([gt.betas, gt.pose, gt.global_orient, gt.transl]),
                keypoints_m=gt.keypoints_3d, model_file=model_file, views=views))
    return out


def read_file(key: str) -> bytes:
    return Path(key).read_bytes()


def test_freihand_parameters_pose_the_model_back_for_any_camera():
    arrays = load_hand_model(None)
    rng = np.random.default_rng(0)
    for _ in range(3):
        theta = np.concatenate([rng.normal(0, 0.5, 10), rng.normal(0, 0.3, 45), Rotation.random(
            random_state=int(rng.integers(1000))).as_rotvec(), rng.normal(0, 0.05, 3)])
        R = Rotation.random(random_state=int(rng.integers(1000))).as_matrix()
        t = np.array([0.0, 0.0, 0.6]) + rng.normal(0, 0.02, 3)
        view = ViewRecord("c", 200, 150, np.array([[300.0, 0, 101], [0, 300.0, 74], [0, 0, 1]]), np.zeros(5), R, t,
                          "unused")
        mesh = posed_mesh(arrays, HandParams.from_theta(theta))
        keypoints, vertices = mesh.keypoints, mesh.vertices
        xyz = keypoints @ R.T + t
        mano = freihand_theta(HandParams.from_theta(theta), view, xyz, arrays)
        assert mano.shape == (61,)
        np.testing.assert_allclose(mano[3:48] + arrays.hands_mean, theta[10:55])  # articulation vs hands_mean
        np.testing.assert_allclose(mano[48:58], theta[:10])
        back_xyz, back_verts = mesh_from_freihand(arrays, mano, view.K)
        np.testing.assert_allclose(back_xyz, xyz, atol=1e-9)
        np.testing.assert_allclose(back_verts, vertices @ R.T + t, atol=1e-9)


def test_composites_replace_the_background_and_keep_the_hand(capture, tmp_path):
    out = tmp_path / "fh"
    summary = write_freihand(records_of(capture), out, read_file, load_hand_model(None),
                             ExportOptions(composites=2, mesh_formats=()))
    n = summary.samples["training"]
    assert n == 2 * len(capture.cameras) and summary.images["training"] == 3 * n and summary.meshes == 0
    data = read_freihand_set(out, "training")
    assert len(data) == n and not list((out / "evaluation" / "rgb").iterdir())
    for i in (0, n - 1):
        original = cv2.imread(str(out / "training" / "rgb" / f"{i:08d}.jpg")).astype(float)
        first, second = (cv2.imread(str(out / "training" / "rgb" / f"{i + n * v:08d}.jpg")).astype(float)
                         for v in (1, 2))
        hand = cv2.imread(str(out / "training" / "mask" / f"{i:08d}.jpg"), cv2.IMREAD_GRAYSCALE) > 127
        core = cv2.erode(hand.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        background = ~cv2.dilate(hand.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
        if core.sum() > 10:  # the hand's pixels stay (JPEG aside); the background changes
            assert np.abs(first[core] - original[core]).mean() < 12
        assert np.abs(first[background] - original[background]).mean() > 20
        assert np.abs(first[background] - second[background]).mean() > 5  # two different backgrounds


def test_wrong_hand_model_and_inconsistent_fits_are_refused(capture, tmp_path):
    arrays = load_hand_model(None)
    with pytest.raises(ExportError, match=r"was made with 'MANO_RIGHT\.pkl'"):
        write_freihand(records_of(capture, "MANO_RIGHT.pkl"), tmp_path / "a", read_file, arrays)
    bad = records_of(capture)
    bad[1] = SampleRecord(**{**bad[1].__dict__, "keypoints_m": bad[1].keypoints_m + 0.01})
    with pytest.raises(ExportError, match=r"differ by 17\.3 mm"):
        write_freihand(bad, tmp_path / "b", read_file, arrays)
    assert not (tmp_path / "b").exists() and list(tmp_path.iterdir()) == []
    with pytest.raises(ExportError, match="no accepted samples"):
        write_freihand([], tmp_path / "c", read_file, arrays)
    with pytest.raises(ValueError, match="params must have shape"):
        SampleRecord(**{**bad[0].__dict__, "params": np.zeros(60)})


def test_left_hands_are_posed_with_the_left_model_and_named_in_the_manifest(tmp_path):
    import json

    from workers.synth.generator import generate_capture
    from workers.synth.plan import SynthConfig

    out = tmp_path / "left-capture"
    generate_capture(out, SynthConfig(num_sequences=1, frames_per_sequence=1, seed=5, width_px=64, side="left"),
                     workers=1)
    left_capture = read_capture(out)
    records = [SampleRecord(**{**r.__dict__, "side": "left"}) for r in records_of(left_capture)]
    right, left = load_hand_model(None, "right"), load_hand_model(None, "left")
    with pytest.raises(ExportError, match=r"sample 1 is a left hand, but the export was given only the right"):
        write_freihand(records, tmp_path / "a", read_file, right, ExportOptions(mesh_formats=()))
    # Posed with the right model, the left hand's parameters do not give its keypoints: refused, not mislabelled.
    wrong = [SampleRecord(**{**r.__dict__, "side": "right"}) for r in records]
    with pytest.raises(ExportError, match=r"\(right\) posed with its parameters"):
        write_freihand(wrong, tmp_path / "b", read_file, right, ExportOptions(mesh_formats=()))
    summary = write_freihand(records, tmp_path / "c", read_file, right, ExportOptions(mesh_formats=()),
                             other_side=left)
    assert summary.samples["training"] == len(left_capture.cameras)
    manifest = json.loads((tmp_path / "c" / "handloop_export.json").read_text())
    assert manifest["hand_model"]["sides"] == ["left"]
    assert {s["side"] for s in manifest["sets"]["training"]["samples"]} == {"left"}
    data = read_freihand_set(tmp_path / "c", "training")
    back, _ = mesh_from_freihand(left, np.asarray(data.mano[0]).reshape(-1), data.K[0])
    np.testing.assert_allclose(back, data.xyz[0], atol=1e-6)  # FreiHAND's parameters pose the left model back


def test_the_manifest_carries_the_audit_figures(capture, tmp_path):
    import json

    quality = {"streams": {"heuristic": {"audited": 20, "wrong": 1, "error_rate": 0.05,
                                         "error_rate_ci95": [0.0089, 0.2361]}}, "rounds": []}
    write_freihand(records_of(capture)[:1], tmp_path / "q", read_file, load_hand_model(None),
                   ExportOptions(mesh_formats=()), label_quality=quality)
    assert json.loads((tmp_path / "q" / "handloop_export.json").read_text())["quality"] == quality
    write_freihand(records_of(capture)[:1], tmp_path / "none", read_file, load_hand_model(None),
                   ExportOptions(mesh_formats=()))
    assert "quality" not in json.loads((tmp_path / "none" / "handloop_export.json").read_text())
