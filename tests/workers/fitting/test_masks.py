"""The wrist cut removes the forearm from a chroma-key-like mask and keeps the hand."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from workers.fitting.masks import MIN_CUT_ANGLE_DEG, boundary_points, cut_forearm, mask_pixels, outside_distance_px
from workers.geometry.rig import default_rig
from workers.rendering import rasterize

ARM_ROTATION = cv2.Rodrigues(np.array([0.3, -0.5, 0.2]))[0]  # a tilted arm, aligned with no axis


def _cylinder(x0: float, x1: float, radius: float) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.cylinder(radius=radius, segment=[[x0, 0, 0], [x1, 0, 0]], sections=24)
    return np.asarray(mesh.vertices) @ ARM_ROTATION.T, np.asarray(mesh.faces)


@pytest.mark.parametrize("camera_index", range(8))
def test_cut_keeps_hand_and_removes_forearm(camera_index):
    """Depth-correct renders of a 'hand' cylinder beyond the wrist and a forearm leaving the picture."""
    camera = default_rig()[camera_index]
    hand_v, hand_f = _cylinder(0.0, 0.17, 0.035)
    arm_v, arm_f = _cylinder(-0.6, -0.002, 0.03)
    fragments = rasterize(np.concatenate([hand_v, arm_v]), np.concatenate([hand_f, arm_f + len(hand_v)]),
                          [camera], with_bary=False)[0]
    hand = (fragments.face_ids >= 0) & (fragments.face_ids < len(hand_f))
    forearm = fragments.face_ids >= len(hand_f)
    cut = cut_forearm(hand | forearm, camera, np.zeros(3), ARM_ROTATION @ np.array([1.0, 0, 0]))
    assert (cut & hand).sum() >= 0.9 * hand.sum()
    assert (cut & forearm).sum() <= 0.05 * forearm.sum()


def test_view_along_the_forearm_is_left_uncut():
    camera = default_rig()[7]
    axis = -camera.center_world / np.linalg.norm(camera.center_world)  # pointing away from the camera
    assert MIN_CUT_ANGLE_DEG > 0
    mask = np.zeros((camera.height, camera.width), dtype=bool)
    mask[100:150, 100:150] = True
    assert np.array_equal(cut_forearm(mask, camera, np.zeros(3), axis), mask)


def test_the_model_silhouette_is_rendered_only_for_a_view_along_the_forearm():
    """A function in place of the silhouette is called for a view the cut cannot serve, and only there."""
    along = default_rig()[7]
    axis = -along.center_world / np.linalg.norm(along.center_world)
    mask = np.zeros((along.height, along.width), dtype=bool)
    mask[100:150, 100:150] = True
    silhouette = np.zeros_like(mask)
    silhouette[110:130, 110:130] = True
    calls: list[int] = []

    def render() -> np.ndarray:
        calls.append(1)
        return silhouette

    assert np.array_equal(cut_forearm(mask, along, np.zeros(3), axis, model_silhouette=render),
                          cut_forearm(mask, along, np.zeros(3), axis, model_silhouette=silhouette))
    assert len(calls) == 1
    across = default_rig()[0]
    hand_v, hand_f = _cylinder(0.0, 0.17, 0.035)
    arm = rasterize(hand_v, hand_f, [across], with_bary=False)[0].face_ids >= 0
    cut_forearm(arm, across, np.zeros(3), ARM_ROTATION @ np.array([1.0, 0, 0]), model_silhouette=render)
    assert len(calls) == 1


@pytest.mark.parametrize("camera_index", [0, 3])
def test_a_cut_from_prepared_pixels_equals_one_that_prepares_them(camera_index):
    camera = default_rig()[camera_index]
    hand_v, hand_f = _cylinder(0.0, 0.17, 0.035)
    arm_v, arm_f = _cylinder(-0.6, -0.002, 0.03)
    mask = rasterize(np.concatenate([hand_v, arm_v]), np.concatenate([hand_f, arm_f + len(hand_v)]), [camera],
                     with_bary=False)[0].face_ids >= 0
    axis = ARM_ROTATION @ np.array([1.0, 0, 0])
    pixels = mask_pixels(mask, camera)
    assert len(pixels.rows) == mask.sum() and pixels.ideal_px.shape == (mask.sum(), 2)
    cut = cut_forearm(mask, camera, np.zeros(3), axis, pixels=pixels)
    assert np.array_equal(cut, cut_forearm(mask, camera, np.zeros(3), axis))
    assert 0 < cut.sum() < mask.sum()


def test_distance_field_and_boundary():
    mask = np.zeros((30, 40), dtype=bool)
    mask[10:20, 10:20] = True
    dist = outside_distance_px(mask)
    assert dist[15, 15] == 0 and abs(dist[15, 25] - 6) < 0.01
    pts = boundary_points(mask, 16, np.random.default_rng(0))
    assert len(pts) == 16
    assert np.all((pts >= 10) & (pts <= 19)) and np.any(pts == 10) and np.any(pts == 19)
    assert outside_distance_px(np.zeros((5, 5), dtype=bool)).min() > 0


def test_boundary_skips_the_cut_line():
    mask = np.zeros((30, 40), dtype=bool)
    mask[10:20, 5:35] = True
    hand = mask.copy()
    hand[:, :20] = False  # cut at x = 20
    pts = boundary_points(hand, 200, np.random.default_rng(0), exclude=mask & ~hand)
    assert len(pts) > 0 and pts[:, 0].min() >= 22


def test_boundary_normals_point_out_of_the_mask():
    from workers.fitting.masks import boundary_samples

    mask = np.zeros((40, 50), dtype=bool)
    mask[10:30, 10:40] = True
    pts, normals = boundary_samples(mask, 400, np.random.default_rng(0))
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    mid_right = (pts[:, 0] == 39) & (pts[:, 1] > 14) & (pts[:, 1] < 25)
    mid_top = (pts[:, 1] == 10) & (pts[:, 0] > 14) & (pts[:, 0] < 35)
    assert mid_right.any() and mid_top.any()
    assert np.allclose(normals[mid_right], [1.0, 0.0])
    assert np.allclose(normals[mid_top], [0.0, -1.0])
    # boundary_points is the same sampling without the normals
    assert np.array_equal(boundary_points(mask, 50, np.random.default_rng(1)),
                          boundary_samples(mask, 50, np.random.default_rng(1))[0])
