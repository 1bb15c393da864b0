"""Per-view visibility of the 21 keypoints of a rendered hand.

A keypoint is visible in a view when it projects inside the image, in front of the camera, and
nothing occludes it at its pixel: another part (a held object) may not be in front of it at all, the
hand's own surface (or the forearm's, at the wrist) at most a tolerance. Joints sit inside the skin,
so the tolerance is the keypoint's distance to the nearest hand vertex (its local skin depth) times a
margin, plus a few millimetres.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from workers.rendering.rasterizer import Fragments


def skin_depth_tolerance_m(keypoints: np.ndarray, hand_vertices: np.ndarray, *, factor: float = 1.4,
                           margin_m: float = 0.005) -> np.ndarray:
    """(21,) depth tolerance per keypoint, metres: factor * distance to the nearest hand vertex + margin.

    Args:
        keypoints: (21, 3) metres, world frame.
        hand_vertices: (V, 3) metres, world frame.
    """
    dist, _ = cKDTree(hand_vertices).query(keypoints)
    return factor * dist + margin_m


def keypoint_visibility(pixels: np.ndarray, depth_m: np.ndarray, fragments: list[Fragments],
                        part_ids: list[np.ndarray], see_through_parts: tuple[int, ...],
                        tolerance_m: np.ndarray) -> np.ndarray:
    """Visibility of N points in C views.

    Args:
        pixels: (C, N, 2) projected points, pixels.
        depth_m: (C, N) camera-frame depth of the points, metres.
        fragments: C z-buffers of the whole scene.
        part_ids: C (H, W) int maps of the visible part (-1 background).
        see_through_parts: parts that count as the point's own surface (hand, forearm); any other part
            (a held object) in front of the point hides it.
        tolerance_m: (N,) how far in front of the point its own surface may be, metres.
    Returns:
        (C, N) bool.
    """
    C, N = depth_m.shape
    visible = np.zeros((C, N), dtype=bool)
    for c, (frags, parts) in enumerate(zip(fragments, part_ids, strict=True)):
        H, W = frags.face_ids.shape
        uv = np.clip(np.nan_to_num(pixels[c], nan=-1.0), -1, max(H, W))  # safe to cast; -1 stays outside
        u = np.rint(uv[:, 0]).astype(np.int64)
        v = np.rint(uv[:, 1]).astype(np.int64)
        inside = (u >= 0) & (u < W) & (v >= 0) & (v < H) & (depth_m[c] > 0) & np.isfinite(pixels[c]).all(1)
        uu, vv = np.clip(u, 0, W - 1), np.clip(v, 0, H - 1)
        in_front_m = depth_m[c] - frags.depth_m[vv, uu]  # > 0: the visible surface is nearer than the point
        own = np.isin(parts[vv, uu], see_through_parts)
        background = parts[vv, uu] < 0
        occluded = ~background & np.where(own, in_front_m > tolerance_m, in_front_m > 0)
        visible[c] = inside & ~occluded
    return visible
