"""Keypoint visibility in a controlled scene; green spill and chroma key on a simple image."""

from __future__ import annotations

import numpy as np
import trimesh

from workers.geometry import default_rig, project_points
from workers.rendering import DirectionalLight, MeshPart, ShadingSettings, render_views
from workers.synth.compositing import apply_green_spill, camera_image, chroma_key
from workers.synth.visibility import keypoint_visibility, skin_depth_tolerance_m


def test_point_behind_an_occluder_is_invisible_only_in_that_view():
    cams = default_rig(96)
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.02)  # "hand" around the keypoint
    points = np.zeros((2, 3))
    points[1] = (0.0, 0.0, 0.019)  # a second keypoint, just under the top of the ball
    blocker_pos = 0.12 * cams[0].center_world / np.linalg.norm(cams[0].center_world)  # towards cam0
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    box.apply_translation(blocker_pos)
    parts = [MeshPart("hand", ball.vertices, ball.faces, np.ones(3)),
             MeshPart("object", box.vertices, box.faces, np.ones(3), closed=True)]
    views = render_views(parts, cams, ShadingSettings(lights=(DirectionalLight((0, 0, -1.0)),)))
    pixels, depth = project_points(points, cams)
    tol = skin_depth_tolerance_m(points, ball.vertices)
    vis = keypoint_visibility(pixels, depth, [v.fragments for v in views], [v.part_ids for v in views], (0,), tol)
    assert not vis[0, 0] and not vis[0, 1]  # behind the box in cam0
    opposite = int(np.argmin([c.center_world @ cams[0].center_world for c in cams]))
    assert vis[opposite, 0]  # the centre is within its skin depth of the surface
    # A view that sees the ball's top sees the top keypoint.
    top = [c for c in range(8) if cams[c].center_world[2] > 0 and c != 0]
    assert all(vis[c, 1] for c in top)
    # Outside the image: invisible.
    far = project_points(np.array([[5.0, 0, 0]]), cams)
    assert not keypoint_visibility(far[0], far[1], [v.fragments for v in views], [v.part_ids for v in views],
                                   (0,), np.array([0.01])).any()


def test_green_spill_tints_the_edge_and_chroma_key_separates_subject():
    h, w = 60, 80
    mask = np.zeros((h, w), bool)
    mask[15:45, 20:60] = True
    skin = np.zeros((h, w, 3), np.float32)
    skin[mask] = (0.75, 0.55, 0.45)
    tinted = apply_green_spill(skin.copy(), mask, strength=0.4, width_px=1.5)
    edge, inside = tinted[15, 40], tinted[30, 40]
    assert edge[1] > inside[1] and edge[0] < inside[0]
    assert np.allclose(inside, (0.75, 0.55, 0.45), atol=1e-3)
    background = np.broadcast_to(np.array([0.16, 0.62, 0.25], np.float32), (h, w, 3)).copy()
    linear = np.power(skin, 2.2)
    image = camera_image(linear, mask, background, spill=0.4, noise=None)
    assert image.dtype == np.uint8 and image.shape == (h, w, 3)
    keyed = chroma_key(image)
    assert keyed[mask].mean() > 0.9 and not keyed[~mask].any()


def test_an_object_hides_a_point_even_within_the_skin_tolerance():
    """Own skin may lie up to the tolerance in front of a joint; a foreign part may not lie in front at all."""
    cams = default_rig(320)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    point = np.zeros((1, 3))
    tol = skin_depth_tolerance_m(point, ball.vertices)
    assert tol[0] > 0.03
    towards = cams[0].center_world / np.linalg.norm(cams[0].center_world)
    cube = trimesh.creation.box(extents=(0.008, 0.008, 0.008))
    cube.apply_translation(0.022 * towards)  # pokes out of the ball towards cam0, within the tolerance
    parts = [MeshPart("hand", ball.vertices, ball.faces, np.ones(3)),
             MeshPart("object", cube.vertices, cube.faces, np.ones(3), closed=True)]
    views = render_views(parts, cams[:1], ShadingSettings())
    pixels, depth = project_points(point, cams[:1])
    u, v = np.rint(pixels[0, 0]).astype(int)
    assert views[0].part_ids[v, u] == 1 and depth[0, 0] - views[0].fragments.depth_m[v, u] < tol[0]
    vis = keypoint_visibility(pixels, depth, [views[0].fragments], [views[0].part_ids], (0,), tol)
    assert not vis[0, 0]
    # Without the cube the same point counts as visible (its own skin is within the tolerance).
    alone = render_views(parts[:1], cams[:1], ShadingSettings())
    assert keypoint_visibility(pixels, depth, [alone[0].fragments], [alone[0].part_ids], (0,), tol)[0, 0]
