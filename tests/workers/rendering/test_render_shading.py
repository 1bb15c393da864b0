"""Shading: normals, Lambert response, multi-part scenes."""

from __future__ import annotations

import numpy as np
import trimesh

from workers.geometry import Camera
from workers.rendering import DirectionalLight, MeshPart, ShadingSettings, render_views, vertex_normals


def camera_on_minus_z() -> Camera:
    """Looks along +z from (0, 0, -1) (identity rotation, t = (0, 0, 1))."""
    K = np.array([[120.0, 0, 47.5], [0, 120.0, 39.5], [0, 0, 1]])
    return Camera("cam", 96, 80, K, np.zeros(5), np.eye(3), np.array([0.0, 0.0, 1.0]))


def test_sphere_normals_point_outwards():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
    n = vertex_normals(sphere.vertices, sphere.faces)
    radial = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    assert np.min(np.einsum("nd,nd->n", n, radial)) > 0.99


def test_lit_side_is_brighter_and_parts_are_labelled():
    cam = camera_on_minus_z()
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.15)
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    box.apply_translation([0.0, 0.0, -0.3])  # between camera and sphere, at the centre
    light_from_left = ShadingSettings(ambient_rgb=(0.1, 0.1, 0.1),
                                      lights=(DirectionalLight((1.0, 0.0, 0.0)),), headlight=0.0, specular=0.0)
    parts = [MeshPart("sphere", sphere.vertices, sphere.faces, np.array([0.8, 0.6, 0.5])),
             MeshPart("box", box.vertices, box.faces, np.array([0.2, 0.2, 0.9]), closed=True)]
    view = render_views(parts, [cam], light_from_left)[0]
    assert view.part_ids[40, 48] == 1  # the box hides the sphere's centre
    row = view.color[40]
    left, right = row[:40][view.part_ids[40, :40] == 0], row[56:][view.part_ids[40, 56:] == 0]
    # Light travels +x, so it comes from -x: image left (x right in the camera) is lit.
    assert left[:, 0].mean() > 2 * right[:, 0].mean()
    assert np.all(view.color[view.part_ids < 0] == 0)
