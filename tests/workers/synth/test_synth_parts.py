"""Subjects, plans, props and motion of the synthetic generator."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from workers.synth.motion import evaluate, hand_axes, plan_motion, slerp
from workers.synth.plan import SynthConfig, num_evaluation, plan_capture
from workers.synth.props import ForearmStyle, HeldObject, WristOpening, forearm_mesh, object_mesh
from workers.synth.subjects import MONK_SKIN_TONES, sample_subjects


def test_subjects_stay_within_two_sd_and_use_monk_tones():
    subjects = sample_subjects(30, np.random.default_rng(0))
    assert all(np.all(np.abs(s.betas) <= 2.0) for s in subjects)
    assert {s.skin_tone for s in subjects} == set(MONK_SKIN_TONES)


@pytest.mark.parametrize(("n", "n_eval"), [(1, 0), (2, 1), (3, 1), (4, 1), (8, 2), (12, 3)])
def test_split_rule(n, n_eval):
    assert num_evaluation(n) == n_eval
    _, plans = plan_capture(SynthConfig(n, 1))
    assert [p.split for p in plans] == ["train"] * (n - n_eval) + ["evaluation"] * n_eval
    assert all(p.green_screen == (p.split == "train") for p in plans)
    assert [p.held_object is not None for p in plans] == [i % 2 == 1 for i in range(n)]


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="num_sequences"):
        SynthConfig(0, 1)
    with pytest.raises(ValueError, match="width_px"):
        SynthConfig(1, 1, width_px=8)


@pytest.mark.parametrize("kind", ["ball", "cylinder", "box"])
def test_objects_are_closed_and_outward(kind):
    rng = np.random.default_rng(1)
    forward = np.array([0.0, 1.0, 0.0])
    palm = Rotation.from_rotvec(rng.normal(size=3)).apply([0.0, 0.0, -1.0])
    palm -= (palm @ forward) * forward
    palm /= np.linalg.norm(palm)
    v, f = object_mesh(HeldObject(kind, (0.03, 0.03, 0.12), (1.0, 0.0, 0.0)), np.array([0.1, 0.2, 0.3]),
                       forward, palm)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.volume > 0  # positive volume: faces counter-clockwise outside


def test_forearm_faces_point_away_from_its_axis_and_sleeve_is_sharp():
    axis = np.array([0.0, -1.0, 0.0])
    style = ForearmStyle(sleeve_start_m=0.2, sleeve_rgb=(0.0, 0.0, 1.0))
    v, f, albedo = forearm_mesh(np.zeros(3), axis, -axis, np.array([0.0, 0.0, 1.0]), WristOpening(0.02, (0.03, 0.02)),
                                style, np.array([1.0, 0.8, 0.6]))
    centers = v[f].mean(axis=1)
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    radial = centers - np.outer(centers @ axis, axis)
    outward = np.einsum("nd,nd->n", normals, radial)
    assert np.all(outward > -1e-12) and np.mean(outward > 0) > 0.95  # the cuff step faces along the axis
    along = v @ axis
    sleeve = albedo[:, 2] == 1.0
    assert along[sleeve].min() == pytest.approx(0.2) and along[~sleeve].max() == pytest.approx(0.2)
    assert along.min() == pytest.approx(0.016)  # starts 4 mm inside the hand mesh's end


def test_motion_is_smooth_and_passes_through_its_keys():
    rng = np.random.default_rng(0)
    keypoints = np.zeros((21, 3))
    keypoints[9] = (0, 0.09, 0)
    keypoints[5], keypoints[17] = (0.03, 0.08, 0), (-0.03, 0.07, 0)
    keys = rng.normal(0, 0.4, (6, 45))
    plan = plan_motion(rng, 40, keys, hand_axes(keypoints))
    fine = evaluate(plan, np.linspace(0, 39, 40 * 8))
    # No jumps: the largest change between neighbouring samples is a small multiple of the mean.
    for series in (fine.pose, fine.global_orient, fine.wrist_m):
        steps = np.linalg.norm(np.diff(series, axis=0), axis=1)
        assert steps.max() < 6 * steps.mean() + 1e-9
    at_keys = evaluate(plan, plan.key_frames)
    np.testing.assert_allclose(at_keys.wrist_m, plan.key_wrist_m, atol=1e-12)
    key_rot = Rotation.from_rotvec(plan.key_orient)
    assert np.all((Rotation.from_rotvec(at_keys.global_orient) * key_rot.inv()).magnitude() < 1e-6)
    # The forearm points out of the -y face, within its tilt limit.
    assert np.all(fine.forearm_axis[:, 1] < -np.cos(np.deg2rad(8.5)))


def test_slerp_endpoints_and_midpoint():
    q0 = Rotation.from_rotvec([0, 0, 0]).as_quat()
    q1 = Rotation.from_rotvec([0, 0, 1.0]).as_quat()
    mid = slerp(q0[None], q1[None], np.array([0.5]))
    assert Rotation.from_quat(mid).as_rotvec()[0] == pytest.approx([0, 0, 0.5])
