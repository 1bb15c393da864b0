"""Tests of the built-in procedural hand (workers/handmodel/builtin)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from smplx.lbs import lbs

from workers.handmodel.builtin import SHAPE_NAMES, build_builtin_hand, cache, mirror_arrays
from workers.handmodel.builtin import build as build_mod
from workers.handmodel.builtin.checks import count_self_intersections
from workers.handmodel.keypoints import MANO_PARENTS
from workers.handmodel.limits import angles_to_pose, joint_frames
from workers.handmodel.pose_sampler import canonical_poses

FIELDS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "parents", "faces",
          "hands_components", "hands_mean", "fingertip_vertex_ids")
MIDDLE, INDEX, RING, PINKY, THUMB = 1 + 1, 1, 3, 4, 0  # positions in fingertip order


@pytest.fixture(scope="module")
def hand():
    return build_builtin_hand("right")


def posed(arrays, pose: np.ndarray, betas: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Reference skinning with smplx.lbs: pose (45,) -> (vertices (V, 3), joints (16, 3))."""
    t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float64)  # noqa: E731
    full = torch.cat([torch.zeros(1, 3, dtype=torch.float64), t(pose)[None]], 1)
    b = torch.zeros(1, 10, dtype=torch.float64) if betas is None else t(betas)[None]
    v, J = lbs(b, full, t(arrays.v_template), t(arrays.shapedirs),
               t(arrays.posedirs.reshape(arrays.num_vertices * 3, -1).T), t(arrays.J_regressor),
               torch.as_tensor(arrays.parents), t(arrays.weights))
    return v[0].numpy(), J[0].numpy()


def measures(arrays, betas: np.ndarray | None = None) -> dict[str, float]:
    """Hand measurements (metres) of the shaped rest mesh."""
    v = arrays.v_template + (0 if betas is None else arrays.shapedirs @ betas)
    J = arrays.J_regressor @ v
    tips = v[arrays.fingertip_vertex_ids]
    thumb_w = arrays.weights[:, 13:16].sum(1)
    slab = (v[:, 0] > 0.055) & (v[:, 0] < 0.075) & (thumb_w < 0.5)
    palm = (arrays.weights[:, 0] > 0.9) & (v[:, 0] > 0.02) & (v[:, 0] < 0.06)
    mid_ring = (arrays.weights[:, 5] > 0.9)
    axis = J[6] - J[5]
    axis /= np.linalg.norm(axis)
    rel = v[mid_ring] - J[5]
    girth = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1).mean()
    return {
        "hand_length": tips[MIDDLE, 0] - J[0, 0],
        "breadth": np.ptp(v[slab, 2]),
        "palm_length": np.linalg.norm(J[4] - J[0]),
        "palm_thickness": np.ptp(v[palm, 1]),
        "index": np.linalg.norm(tips[INDEX] - J[1]),
        "middle": np.linalg.norm(tips[MIDDLE] - J[4]),
        "ring": np.linalg.norm(tips[RING] - J[10]),
        "pinky": np.linalg.norm(tips[PINKY] - J[7]),
        "thumb": np.linalg.norm(tips[THUMB] - J[14]) + np.linalg.norm(J[14] - J[13]),
        "finger_girth": girth,
    }


def test_validates_and_describes_itself(hand):
    assert hand.validate() is hand
    assert hand.name == "handloop-builtin v1" and not hand.is_mano and hand.side == "right"
    assert "HANDLOOP_MANO_PATH" in hand.source_note and "MANO" in hand.source_note
    assert 800 <= hand.num_vertices <= 2000
    assert tuple(hand.parents) == MANO_PARENTS
    assert hand.extras["shape_names"] == SHAPE_NAMES
    assert (hand.weights >= 0).all() and (hand.J_regressor >= 0).all()


def test_fresh_build_is_bit_identical_to_the_cached_copy(hand):
    fresh = build_builtin_hand("right", use_cache=False)
    for key in FIELDS:
        a, b = getattr(fresh, key), getattr(hand, key)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), key


def test_cache_rejects_corrupt_and_stale_files(tmp_path, monkeypatch, hand):
    monkeypatch.setenv("HANDLOOP_DATA_DIR", str(tmp_path))
    assert cache.cache_dir() == tmp_path / "cache"
    path = tmp_path / "cache" / "hand.npz"
    data = {key: getattr(hand, key) for key in FIELDS}
    cache.save_npz(path, {**data, "generator_version": np.array("v-old")})
    assert cache.load_npz(path, "v-new", FIELDS) is None  # stale
    loaded = cache.load_npz(path, "v-old", FIELDS)
    assert loaded is not None and loaded["faces"].tobytes() == hand.faces.tobytes()
    path.write_bytes(b"not a zip file")
    assert cache.load_npz(path, "v-old", FIELDS) is None  # corrupt
    assert cache.load_npz(tmp_path / "missing.npz", "v-old", FIELDS) is None
    assert build_mod.cache_key().startswith(build_mod.GENERATOR_VERSION)


def test_surface_is_closed_outward_and_free_of_self_intersections(hand):
    mesh = trimesh.Trimesh(hand.v_template, hand.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 2e-4  # an adult hand is ~3.5e-4 m^3
    assert mesh.euler_number == 2  # a sphere-like closed surface (no handles)
    assert count_self_intersections(hand.v_template, hand.faces) == 0


def test_self_intersection_check_detects_overlap(hand):
    v = np.concatenate([hand.v_template, hand.v_template + np.array([0.01, 0.0, 0.0])])
    f = np.concatenate([hand.faces, hand.faces + hand.num_vertices])
    assert count_self_intersections(v, f) > 0


def test_rest_frame_and_adult_proportions(hand):
    J = hand.J_regressor @ hand.v_template
    assert np.allclose(J[0], 0.0, atol=1e-6)  # wrist joint at the origin
    m = measures(hand)
    assert 0.180 <= m["hand_length"] <= 0.200
    assert 0.078 <= m["breadth"] <= 0.092
    # wrist to middle MCP joint ~0.446 HL (Buchholz); the skin palm length (~0.6 HL) ends at the finger crease
    assert 0.42 <= m["palm_length"] / m["hand_length"] <= 0.47
    assert m["middle"] > m["ring"] > m["pinky"] and m["middle"] > m["index"] > m["pinky"]
    assert abs(m["ring"] - m["index"]) < 0.1 * m["middle"]
    tips = hand.v_template[hand.fingertip_vertex_ids]
    assert tips[MIDDLE, 0] > 0.15 and abs(tips[MIDDLE, 2]) < 0.01  # fingers along +x
    assert tips[THUMB, 2] > 0.05  # thumb toward +z
    thenar = hand.v_template[hand.weights[:, 13] > 0.5]
    assert thenar[:, 1].mean() > 0  # the thumb sits on the palm side (+y)


def test_fingertip_vertices_are_the_extreme_points_of_their_fingers(hand):
    J = hand.J_regressor @ hand.v_template
    for k, last in enumerate((15, 3, 6, 12, 9)):
        axis = hand.v_template[hand.fingertip_vertex_ids[k]] - J[last]
        axis /= np.linalg.norm(axis)
        finger = hand.weights[:, last] > 0.3
        reach = (hand.v_template[finger] - J[last]) @ axis
        tip = (hand.v_template[hand.fingertip_vertex_ids[k]] - J[last]) @ axis
        assert tip >= reach.max() - 1e-4


def test_joint_regressor_hits_the_joint_centres_under_shape_changes(hand):
    from workers.handmodel.builtin.shape import SHAPE_DIRECTIONS, warp_vertices
    from workers.handmodel.builtin.skeleton import build_skeleton

    rest = build_skeleton()
    assert np.abs(hand.J_regressor @ hand.v_template - rest.joints).max() < 1e-5
    for k in (0, 1, 2, 5):
        _, sd, change = SHAPE_DIRECTIONS[k]
        new = build_skeleton(change(rest.proportions, 2 * sd))
        v = warp_vertices(hand.v_template, hand.weights, rest, new)
        assert np.abs(hand.J_regressor @ v - new.joints).max() < 1.5e-3


@pytest.mark.parametrize(("name", "grows", "steady"), [
    ("size", ("hand_length", "breadth", "thumb"), ()),
    ("palm_breadth", ("breadth",), ("middle",)),
    ("finger_length", ("index", "middle", "ring", "pinky", "hand_length"), ("breadth",)),
    ("finger_thickness", ("finger_girth",), ("middle", "palm_length")),
    ("palm_length", ("palm_length", "hand_length"), ("middle",)),
    ("thumb_length", ("thumb",), ("middle", "breadth")),
    ("palm_thickness", ("palm_thickness",), ("middle", "breadth")),
    ("pinky_length", ("pinky",), ("middle",)),
])
def test_shape_directions_change_what_they_claim(hand, name, grows, steady):
    k = SHAPE_NAMES.index(name)
    beta = np.zeros(10)
    beta[k] = 2.0
    lo, hi = measures(hand, -beta), measures(hand, beta)
    base = measures(hand)
    for key in grows:
        assert hi[key] > base[key] * 1.02 > lo[key] * 1.02, key
    for key in steady:
        assert abs(hi[key] - lo[key]) < 0.01 * base[key], key


def test_ratio_shape_directions(hand):
    def ratio(name: str, num: str, den: str) -> tuple[float, float]:
        beta = np.zeros(10)
        beta[SHAPE_NAMES.index(name)] = 2.0
        lo, hi = measures(hand, -beta), measures(hand, beta)
        return lo[num] / lo[den], hi[num] / hi[den]

    lo, hi = ratio("index_ring_ratio", "index", "ring")
    assert hi > lo * 1.05
    lo, hi = ratio("slenderness", "hand_length", "breadth")
    assert hi > lo * 1.05


def test_left_hand_is_the_mirror_image(hand):
    left = build_builtin_hand("left")
    assert left.side == "left"
    assert np.array_equal(left.v_template, hand.v_template * [-1, 1, 1])
    mesh = trimesh.Trimesh(left.v_template, left.faces, process=False)
    assert mesh.is_winding_consistent and mesh.volume > 0
    assert np.array_equal(mirror_arrays(left, "right").faces, hand.faces)
    pose_r = canonical_poses(hand)["pinch"]
    pose_l = canonical_poses(left)["pinch"]
    assert np.allclose(pose_l, pose_r * np.tile([1, -1, -1], 15), atol=1e-9)
    vr, _ = posed(hand, pose_r)
    vl, _ = posed(left, pose_l)
    assert np.allclose(vl, vr * [-1, 1, 1], atol=1e-9)


def test_pose_pca_is_orthonormal_and_centred_on_the_sampler(hand):
    comps = hand.hands_components
    assert np.allclose(comps @ comps.T, np.eye(45), atol=1e-8)
    assert np.linalg.norm(hand.hands_mean) > 0.1  # the sampler's mean pose is not flat
    from workers.handmodel.pose_sampler import pose_bank

    coeffs = (pose_bank(512, seed=3, arrays=hand) - hand.hands_mean) @ comps.T
    var = coeffs.var(axis=0)
    assert var[:5].sum() > 0.5 * var.sum()  # a few synergies explain most of the variance


def test_bent_finger_keeps_its_skin(hand):
    frames = joint_frames(hand)
    angles = np.zeros((15, 3))
    angles[0, 0], angles[1, 0], angles[2, 0] = np.deg2rad([90.0, 100.0, 67.0])  # index MCP, PIP, DIP
    v, _ = posed(hand, angles_to_pose(angles, frames))
    edges = trimesh.Trimesh(hand.v_template, hand.faces, process=False).edges_unique
    moving = hand.weights[:, 1:4].sum(1) > 0.05
    sel = moving[edges[:, 0]] | moving[edges[:, 1]]
    rest_len = np.linalg.norm(np.diff(hand.v_template[edges[sel]], axis=1)[:, 0], axis=1)
    bent_len = np.linalg.norm(np.diff(v[edges[sel]], axis=1)[:, 0], axis=1)
    ratio = bent_len / rest_len
    # the inner crease compresses a few edges (as skin folds); nothing collapses or tears
    assert ratio.min() > 0.15 and np.percentile(ratio, 1) > 0.45 and ratio.max() < 2.0
    vol_rest = trimesh.Trimesh(hand.v_template, hand.faces, process=False).volume
    vol_bent = trimesh.Trimesh(v, hand.faces, process=False).volume
    assert vol_bent > 0.95 * vol_rest
