"""A scene of several coloured meshes (hand, forearm, object) rendered into every view at once.

Parts are merged into one mesh so that one z-buffer pass per view resolves occlusions between them;
`part_ids` tells which part each visible pixel shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import project_points
from workers.rendering.rasterizer import Fragments, rasterize_projected
from workers.rendering.shading import ShadingSettings, shade, vertex_normals


@dataclass(frozen=True)
class MeshPart:
    """One coloured mesh.

    Attributes:
        name: e.g. "hand", "forearm", "object".
        vertices: (V, 3) float, metres, world frame.
        faces: (F, 3) int, counter-clockwise seen from outside.
        albedo_rgb: (V, 3) float linear albedo in [0, 1], or (3,) for a uniform colour.
        closed: the mesh is closed (or its holes are hidden), so its back faces are never seen and are
            culled (faster; leave False for open meshes such as a hand with an open wrist).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    albedo_rgb: np.ndarray
    closed: bool = False


@dataclass(frozen=True)
class ViewRender:
    """One rendered view.

    Attributes:
        color: (H, W, 3) float32 linear RGB in [0, ~1.2] (unclipped), 0 on background.
        part_ids: (H, W) int8 index into the scene's parts of the visible part, -1 on background.
        fragments: the z-buffer (face ids index the merged mesh).
    """

    color: np.ndarray
    part_ids: np.ndarray
    fragments: Fragments


def merge_parts(parts: list[MeshPart]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate parts into one mesh.

    Returns:
        vertices (V, 3) float64, faces (F, 3) int64, albedo (V, 3) float32, normals (V, 3) float64 (per
        part, so creases between parts stay sharp), part_of_face (F,) int8.
        Parts that are `closed` are the ones whose faces `render_views` culls.
    """
    vertices, faces, albedo, normals, part_of_face = [], [], [], [], []
    offset = 0
    for i, part in enumerate(parts):
        v = np.asarray(part.vertices, dtype=np.float64)
        f = np.asarray(part.faces, dtype=np.int64)
        a = np.broadcast_to(np.asarray(part.albedo_rgb, dtype=np.float32), v.shape)
        vertices.append(v)
        faces.append(f + offset)
        albedo.append(a)
        normals.append(vertex_normals(v, f))
        part_of_face.append(np.full(len(f), i, dtype=np.int8))
        offset += len(v)
    return (np.concatenate(vertices), np.concatenate(faces), np.concatenate(albedo).astype(np.float32),
            np.concatenate(normals), np.concatenate(part_of_face))


def render_views(parts: list[MeshPart], cameras: list[Camera], shading: ShadingSettings) -> list[ViewRender]:
    """Rasterize and shade the scene in every camera.

    Args:
        parts: the meshes, world frame, metres.
        cameras: the C views.
        shading: lights (world frame).
    Returns:
        C `ViewRender`s in camera order.
    """
    vertices, faces, albedo, normals, part_of_face = merge_parts(parts)
    cull = np.asarray([p.closed for p in parts], bool)[part_of_face]
    pixels, depth = project_points(vertices, cameras)
    views = []
    for c, cam in enumerate(cameras):
        frags = rasterize_projected(pixels[c], depth[c], faces, cam.width, cam.height, with_bary=True,
                                    cull=cull if cull.any() else None)
        color = shade(frags, faces, vertices, normals, albedo, cam, shading)
        part_ids = np.where(frags.mask, part_of_face[np.maximum(frags.face_ids, 0)], -1).astype(np.int8)
        views.append(ViewRender(color=color, part_ids=part_ids, fragments=frags))
    return views
