"""The vectorised rasterizer against a slow, obviously-correct per-pixel reference."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from workers.geometry import Camera, default_rig, project_points
from workers.rendering import coverage_mask, model_mask, rasterize, rasterize_projected


def reference_rasterize(pixels: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int):
    """Per pixel, per triangle: barycentrics from signed areas, nearest 1/z wins. Slow and plain."""
    face_ids = np.full((height, width), -1)
    depth_out = np.full((height, width), np.inf)
    for y in range(height):
        for x in range(width):
            best = 0.0
            for f, (i, j, k) in enumerate(faces):
                (x0, y0), (x1, y1), (x2, y2) = pixels[i], pixels[j], pixels[k]
                area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
                if abs(area) < 1e-12:
                    continue
                b0 = ((x1 - x) * (y2 - y) - (x2 - x) * (y1 - y)) / area
                b1 = ((x2 - x) * (y0 - y) - (x0 - x) * (y2 - y)) / area
                b2 = 1 - b0 - b1
                if min(b0, b1, b2) < -1e-9:
                    continue
                inv_z = b0 / depth[i] + b1 / depth[j] + b2 / depth[k]
                if inv_z > best:
                    best, face_ids[y, x], depth_out[y, x] = inv_z, f, 1 / inv_z
    return face_ids, depth_out


def pinhole(width: int = 40, height: int = 30, f: float = 40.0) -> Camera:
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    return Camera("cam", width, height, K, np.zeros(5), np.eye(3), np.zeros(3))


def test_matches_slow_reference_on_random_triangles():
    rng = np.random.default_rng(0)
    W, H, F = 24, 18, 14
    pixels = rng.uniform(-4, [W + 3, H + 3], (3 * F, 2))
    depth = rng.uniform(0.5, 2.0, 3 * F)
    faces = np.arange(3 * F).reshape(F, 3)
    fast = rasterize_projected(pixels, depth, faces, W, H)
    ref_ids, ref_depth = reference_rasterize(pixels, depth, faces, W, H)
    assert np.array_equal(fast.face_ids >= 0, ref_ids >= 0)
    covered = ref_ids >= 0
    np.testing.assert_allclose(fast.depth_m[covered], ref_depth[covered], rtol=1e-5)
    # Face ids may only differ where two faces are equally near (within float precision).
    differ = covered & (fast.face_ids != ref_ids)
    assert differ.sum() <= 2


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_overlapping_triangles_nearest_wins_in_both_draw_orders(order):
    cam = pinhole()
    near = np.array([[-0.3, -0.3, 1.0], [0.3, -0.3, 1.0], [0.0, 0.3, 1.0]])
    far = near * np.array([2.6, 2.6, 1.0]) + np.array([0.05, 0.0, 1.0])  # behind, larger in the image
    tris = [near, far]
    vertices = np.concatenate([tris[order[0]], tris[order[1]]])
    frags = rasterize(vertices, np.array([[0, 1, 2], [3, 4, 5]]), [cam])[0]
    near_id = order.index(0)
    centre = frags.face_ids[cam.height // 2, cam.width // 2]
    assert centre == near_id
    assert frags.depth_m[cam.height // 2, cam.width // 2] == pytest.approx(1.0, abs=1e-6)
    # Where only the far triangle reaches, it is visible.
    assert (frags.face_ids == 1 - near_id).any()


def test_barycentrics_are_perspective_correct():
    cam = pinhole(64, 48, 50.0)
    tri = np.array([[-0.4, -0.3, 1.0], [0.5, -0.2, 2.5], [0.0, 0.5, 1.5]])
    frags = rasterize(tri, np.array([[0, 1, 2]]), [cam])[0]
    ys, xs = np.nonzero(frags.mask)
    points = np.einsum("nk,kd->nd", frags.bary[ys, xs].astype(np.float64), tri)
    pixels, depth = project_points(points, [cam])
    # The 3D point the barycentrics describe projects onto the pixel centre, at the buffer's depth.
    np.testing.assert_allclose(pixels[0], np.stack([xs, ys], 1), atol=2e-3)
    np.testing.assert_allclose(depth[0], frags.depth_m[ys, xs], rtol=1e-5)


def test_sphere_silhouette_matches_its_projected_disc():
    cam = pinhole(120, 100, 200.0)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    sphere.apply_translation([0.0, 0.0, 1.0])
    mask = model_mask(sphere.vertices, sphere.faces, cam)
    r_px = 200.0 * 0.1 / np.sqrt(1.0 - 0.1**2)  # tangent cone of the sphere
    assert mask.sum() == pytest.approx(np.pi * r_px**2, rel=0.03)


def test_culling_a_closed_mesh_changes_nothing():
    cam = default_rig(160)[0]
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.15)).subdivide()
    pixels, depth = project_points(box.vertices, [cam])
    full = rasterize_projected(pixels[0], depth[0], box.faces, cam.width, cam.height)
    culled = rasterize_projected(pixels[0], depth[0], box.faces, cam.width, cam.height,
                                 cull=np.ones(len(box.faces), bool))
    assert full.mask.sum() > 500
    assert np.array_equal(full.mask, culled.mask)
    np.testing.assert_allclose(full.depth_m[full.mask], culled.depth_m[full.mask], rtol=1e-6)


def test_coverage_mask_equals_depth_tested_mask_and_handles_offscreen_faces():
    cam = default_rig(96)[3]
    cyl = trimesh.creation.cylinder(radius=0.05, height=3.0, sections=16)  # leaves the picture
    pixels, depth = project_points(cyl.vertices, [cam])
    frags = rasterize_projected(pixels[0], depth[0], cyl.faces, cam.width, cam.height, with_bary=False)
    assert frags.bary is None
    assert np.array_equal(frags.mask, coverage_mask(pixels[0], depth[0], cyl.faces, cam.width, cam.height))


def test_bad_shapes_raise():
    cam = pinhole()
    with pytest.raises(ValueError, match="vertices"):
        rasterize(np.zeros((3, 2)), np.array([[0, 1, 2]]), [cam])
    with pytest.raises(ValueError, match="faces"):
        rasterize(np.zeros((3, 3)), np.array([[0, 1, 5]]), [cam])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 6))
def test_property_matches_reference_coverage_and_depth(seed, n):
    rng = np.random.default_rng(seed)
    W, H = 12, 10
    pixels = rng.uniform(-3, [W + 2, H + 2], (3 * n, 2))
    depth = rng.uniform(0.3, 3.0, 3 * n)
    faces = np.arange(3 * n).reshape(n, 3)
    fast = rasterize_projected(pixels, depth, faces, W, H)
    ref_ids, ref_depth = reference_rasterize(pixels, depth, faces, W, H)
    assert np.array_equal(fast.mask, ref_ids >= 0)
    np.testing.assert_allclose(fast.depth_m[fast.mask], ref_depth[fast.mask], rtol=1e-5)
    np.testing.assert_allclose(fast.bary.sum(axis=2)[fast.mask], 1.0, atol=1e-5)
