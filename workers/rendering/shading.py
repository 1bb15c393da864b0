"""Smooth Lambert shading of rasterized fragments (Gouraud): ambient plus directional lights plus a
faint specular sheen, evaluated per vertex with per-vertex normals and albedo, then interpolated per
pixel with the fragments' perspective-correct barycentrics. At working resolution a hand's vertices are
about a pixel apart, so this looks like per-pixel (Phong) shading at a fraction of the cost.

All directions are in the world frame (z up); colours are linear floats in [0, 1], RGB order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workers.geometry.camera import Camera
from workers.rendering.rasterizer import Fragments


@dataclass(frozen=True)
class DirectionalLight:
    """A light infinitely far away.

    Attributes:
        direction_world: (3,) direction the light travels (from the light to the scene), world frame.
        color_rgb: (3,) intensity per channel, 1 = full white.
    """

    direction_world: tuple[float, float, float]
    color_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class ShadingSettings:
    """Lighting of one view.

    Attributes:
        ambient_rgb: (3,) ambient intensity per channel.
        lights: directional lights in the world frame.
        headlight: intensity of a light travelling along each camera's optical axis (a soft fill that
            keeps surfaces facing the camera from going black), 0..1.
        specular: strength of a Blinn-Phong highlight, 0..1 (skin sheen).
        shininess: Blinn-Phong exponent.
    """

    ambient_rgb: tuple[float, float, float] = (0.35, 0.35, 0.35)
    lights: tuple[DirectionalLight, ...] = field(default_factory=lambda: (
        DirectionalLight((0.3, 0.4, -1.0), (0.75, 0.73, 0.70)),
        DirectionalLight((-0.6, -0.2, 0.3), (0.25, 0.25, 0.28)),
    ))
    headlight: float = 0.25
    specular: float = 0.08
    shininess: float = 24.0


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals.

    Args:
        vertices: (V, 3) float, metres.
        faces: (F, 3) int, counter-clockwise seen from outside.
    Returns:
        (V, 3) float64 unit normals pointing outwards (zero for unused vertices).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # (F, 3), length = 2 area
    normals = np.zeros_like(v)
    for corner in range(3):  # bincount per axis is several times faster than np.add.at
        for axis in range(3):
            normals[:, axis] += np.bincount(f[:, corner], weights=face_n[:, axis], minlength=len(v))
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def interpolate(fragments: Fragments, faces: np.ndarray, vertex_values: np.ndarray) -> np.ndarray:
    """Interpolate per-vertex values at the covered pixels with the fragments' barycentrics.

    Args:
        fragments: one view's fragments, with barycentrics.
        faces: (F, 3) int, the faces the fragments index.
        vertex_values: (V, D) float.
    Returns:
        (N, D) float32 values at the N covered pixels, in row-major pixel order (np.flatnonzero(mask)).
    """
    if fragments.bary is None:
        raise ValueError("fragments have no barycentrics: rasterize with with_bary=True")
    mask = fragments.mask
    fid = fragments.face_ids[mask]
    bary = fragments.bary[mask]  # (N, 3)
    corners = np.asarray(vertex_values, dtype=np.float32)[np.asarray(faces)[fid]]  # (N, 3, D)
    return np.einsum("nk,nkd->nd", bary, corners)


def shade_vertices(vertices_world: np.ndarray, normals_world: np.ndarray, albedo_rgb: np.ndarray,
                   camera: Camera, settings: ShadingSettings) -> np.ndarray:
    """Lit colour of every vertex as seen from `camera`.

    Normals facing clearly away from the camera are flipped (two-sided lighting: the inside of an open
    mesh is lit like its outside). colour = albedo * (ambient + sum of Lambert terms) + specular.

    Args:
        vertices_world: (V, 3) metres, world frame.
        normals_world: (V, 3) unit normals, world frame.
        albedo_rgb: (V, 3) linear albedo in [0, 1].
        camera: the view (viewing directions, headlight).
        settings: lights.
    Returns:
        (V, 3) float32 linear RGB.
    """
    n = np.asarray(normals_world, dtype=np.float64).copy()
    to_cam = camera.center_world[None] - np.asarray(vertices_world, dtype=np.float64)
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True) + 1e-12
    # Flip only normals that clearly face away: silhouette vertices (facing ~sideways) keep theirs, so
    # closed meshes show no speckles along their outline.
    n[np.einsum("nd,nd->n", n, to_cam) < -0.25] *= -1.0
    light = np.tile(np.asarray(settings.ambient_rgb, np.float64), (len(n), 1))
    spec = np.zeros(len(n))
    lights = [(np.asarray(lt.direction_world, np.float64), np.asarray(lt.color_rgb, np.float64))
              for lt in settings.lights]
    if settings.headlight > 0:
        lights.append((camera.R[2], np.full(3, settings.headlight)))
    for direction, color in lights:
        to_light = -direction / np.linalg.norm(direction)
        lambert = np.clip(n @ to_light, 0.0, None)
        light += lambert[:, None] * color[None]
        if settings.specular > 0:
            half = to_light[None] + to_cam
            half /= np.linalg.norm(half, axis=1, keepdims=True) + 1e-12
            spec += settings.specular * float(color.mean()) * np.clip(
                np.einsum("nd,nd->n", n, half), 0.0, None) ** settings.shininess
    return (np.asarray(albedo_rgb) * light + spec[:, None]).astype(np.float32)


def shade(fragments: Fragments, faces: np.ndarray, vertices_world: np.ndarray, normals_world: np.ndarray,
          albedo_rgb: np.ndarray, camera: Camera, settings: ShadingSettings) -> np.ndarray:
    """Shaded colour of every covered pixel of one view (Gouraud: `shade_vertices`, interpolated).

    Args:
        fragments: the view's fragments, with barycentrics.
        faces: (F, 3) int.
        vertices_world: (V, 3) metres, world frame.
        normals_world: (V, 3) unit vertex normals, world frame.
        albedo_rgb: (V, 3) linear albedo in [0, 1].
        camera: the view.
        settings: lights.
    Returns:
        (H, W, 3) float32 linear RGB, 0 on background.
    """
    colors = shade_vertices(vertices_world, normals_world, albedo_rgb, camera, settings)
    image = np.zeros((*fragments.face_ids.shape, 3), np.float32)
    image[fragments.mask] = interpolate(fragments, faces, colors)
    return image
