"""The meshes around the hand: a forearm that leaves the picture, and simple held objects.

World frame, metres. A hand frame is given by three unit vectors: `forward` (wrist towards the middle
knuckle), `palm` (out of the palm) and `lateral` = forward x palm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

FOREARM_LENGTH_M = 4.0  # long enough to leave every view (the upper arm continues the line)
OBJECT_KINDS: tuple[str, ...] = ("cylinder", "box", "ball")


@dataclass(frozen=True)
class ForearmStyle:
    """Per-subject forearm appearance.

    Attributes:
        growth: how much wider the forearm gets towards the elbow, as a fraction of the wrist radii.
        sleeve_start_m: distance from the wrist where a sleeve begins, or None for a bare arm.
        sleeve_rgb: (3,) linear albedo of the sleeve.
    """

    growth: float = 0.35
    sleeve_start_m: float | None = 0.2
    sleeve_rgb: tuple[float, float, float] = (0.1, 0.12, 0.3)


@dataclass(frozen=True)
class HeldObject:
    """A simple object held in the grasp; dimensions in metres, colour as linear albedo.

    Attributes:
        kind: "cylinder" (axis across the palm), "box" (long side across the palm) or "ball".
        size_m: (3,) cylinder: (radius, radius, length); box: (depth, width, length); ball: (r, r, r).
        rgb: (3,) linear albedo.
    """

    kind: str
    size_m: tuple[float, float, float]
    rgb: tuple[float, float, float]


@dataclass(frozen=True)
class WristOpening:
    """Where the hand mesh ends behind the wrist, and how wide it is there.

    Attributes:
        behind_m: distance from the wrist keypoint to the mesh's end, along -forward, metres (>= 0).
        radii_m: (half-width across the palm, half-depth along the palm normal) at the end, metres.
    """

    behind_m: float
    radii_m: tuple[float, float]


def wrist_opening(hand_vertices: np.ndarray, wrist: np.ndarray, forward: np.ndarray, palm: np.ndarray,
                  band_m: float = 0.008) -> WristOpening:
    """Measure the end of the hand mesh behind the wrist (MANO and the built-in hand both end there).

    Args:
        hand_vertices: (V, 3) posed hand vertices, world frame, metres.
        wrist: (3,) wrist keypoint; forward, palm: (3,) unit axes of the hand frame.
        band_m: vertices within this distance of the end are measured.
    """
    rel = hand_vertices - wrist
    along = rel @ forward
    end = min(float(along.min()), 0.0)
    near = along < end + band_m
    if near.sum() < 8:
        return WristOpening(0.0, (0.028, 0.019))
    lateral = np.cross(forward, palm)
    half_width = float(np.percentile(np.abs(rel[near] @ lateral), 90))
    half_depth = float(np.percentile(np.abs(rel[near] @ palm), 90))
    return WristOpening(-end, (float(np.clip(half_width, 0.015, 0.045)), float(np.clip(half_depth, 0.01, 0.035))))


def forearm_mesh(wrist: np.ndarray, axis: np.ndarray, forward: np.ndarray, palm: np.ndarray,
                 opening: WristOpening, style: ForearmStyle, skin_rgb: np.ndarray, *, overlap_m: float = 0.004,
                 bend_m: float = 0.04, length_m: float = FOREARM_LENGTH_M, rings: int = 34, segments: int = 20
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An elliptical, tapered tube that continues the hand mesh from its wrist end out along `axis`.

    The tube starts `overlap_m` inside the hand mesh's end (hiding its opening), first follows the
    hand's own direction and bends smoothly (over `bend_m`) into the forearm's axis, as a flexed wrist does.

    Args:
        wrist: (3,) wrist keypoint, world frame, metres.
        axis: (3,) unit direction from the wrist towards the elbow (out of the rig through -y).
        forward, palm: (3,) unit hand axes (wrist -> middle knuckle; out of the palm).
        opening: where and how wide the hand mesh ends (`wrist_opening`).
        style: widening and sleeve.
        skin_rgb: (3,) linear skin albedo.
    Returns:
        vertices (R * segments, 3) float64 (R = rings, +2 with a sleeve), faces (F, 3) int64 (outward,
        counter-clockwise), albedo (V, 3) float32.
    """
    axis = axis / np.linalg.norm(axis)
    start = max(opening.behind_m - overlap_m, 0.0)
    # Distance along the tube from its start; rings denser near the wrist (curved, visible).
    s = start + (length_m - start) * np.linspace(0.0, 1.0, rings) ** 2.6
    sleeve = np.zeros(rings, bool)
    if style.sleeve_start_m is not None and style.sleeve_start_m > start:
        # Two rings at the cuff, bare then sleeved, so the colour changes sharply there.
        cut = int(np.searchsorted(s, style.sleeve_start_m))
        s = np.concatenate([s[:cut], [style.sleeve_start_m, style.sleeve_start_m], s[cut:]])
        sleeve = np.arange(len(s)) > cut
    # Centre line: along -forward at the start, blending into `axis` (smoothstep over bend_m).
    t = np.clip((s - start) / bend_m, 0.0, 1.0)
    w = (t * t * (3 - 2 * t))[:, None]
    direction = (1 - w) * -forward[None] + w * axis[None]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    centers = wrist[None] + s[:, None] * direction
    tangent = np.gradient(centers, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    depth_dir = palm[None] - np.sum(palm[None] * tangent, axis=1, keepdims=True) * tangent
    depth_dir /= np.linalg.norm(depth_dir, axis=1, keepdims=True)
    width_dir = np.cross(tangent, depth_dir)
    grow = 1.0 + style.growth * np.clip((s - start) / 0.2, 0.0, 1.0) ** 0.7 - 0.15 * np.clip((s - 0.3) / 0.4, 0, 1)
    grow = grow + sleeve * 0.25  # a sleeve is looser than skin
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    a = opening.radii_m[0] * grow[:, None] * np.cos(phi)[None]  # (R, segments)
    b = opening.radii_m[1] * grow[:, None] * np.sin(phi)[None]
    verts = centers[:, None] + a[..., None] * width_dir[:, None] + b[..., None] * depth_dir[:, None]
    R = len(s)
    i, j = np.meshgrid(np.arange(R - 1), np.arange(segments), indexing="ij")
    v00 = i * segments + j
    v01 = i * segments + (j + 1) % segments
    v10 = v00 + segments
    v11 = v01 + segments
    # phi turns from width_dir to depth_dir, i.e. about width x depth = -tangent... as seen along the
    # tube; with rings advancing along +tangent this order makes the normals point outwards.
    faces = np.concatenate([np.stack([v00, v10, v01], -1).reshape(-1, 3),
                            np.stack([v01, v10, v11], -1).reshape(-1, 3)])
    albedo = np.where(sleeve[:, None, None], np.asarray(style.sleeve_rgb, np.float32),
                      np.asarray(skin_rgb, np.float32)).repeat(segments, axis=1)
    return verts.reshape(-1, 3), faces.astype(np.int64), albedo.reshape(-1, 3).astype(np.float32)


def object_mesh(obj: HeldObject, center: np.ndarray, forward: np.ndarray, palm: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """The object's mesh placed at `center`, its long axis across the palm (along forward x palm).

    Args:
        obj: the object.
        center: (3,) world position of its centre, metres.
        forward, palm: (3,) unit hand axes.
    Returns:
        vertices (V, 3) float64 world frame, faces (F, 3) int64 outward.
    """
    if obj.kind == "ball":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=obj.size_m[0])
    elif obj.kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=obj.size_m[0], height=obj.size_m[2], sections=28)
        mesh = mesh.subdivide()  # long side triangles would span the whole object: keep them small
    elif obj.kind == "box":
        mesh = trimesh.creation.box(extents=obj.size_m).subdivide().subdivide()
    else:
        raise ValueError(f"unknown object kind {obj.kind!r}; choose from {OBJECT_KINDS}")
    # Local x -> palm normal (depth), y -> forward, z (long axis) -> across the palm; a proper rotation
    # (det +1), so faces stay counter-clockwise seen from outside (back-face culling relies on it).
    R = np.stack([palm, forward, np.cross(palm, forward)], axis=1)
    return mesh.vertices @ R.T + center, np.asarray(mesh.faces, dtype=np.int64)


def grasp_center(keypoints: np.ndarray, palm: np.ndarray, obj: HeldObject) -> np.ndarray:
    """Where the object sits: in front of the palm, between the knuckles and the wrist.

    Args:
        keypoints: (21, 3) FreiHAND keypoints, world frame.
        palm: (3,) unit palm normal.
        obj: the object (its depth sets the distance from the palm).
    Returns:
        (3,) world position, metres.
    """
    knuckles = keypoints[[5, 9, 13, 17]].mean(axis=0)
    palm_center = 0.55 * knuckles + 0.45 * keypoints[0]
    half_depth = obj.size_m[0]
    return palm_center + palm * (half_depth + 0.012)
