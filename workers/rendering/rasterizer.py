"""A depth-correct CPU triangle rasterizer for meshes seen through calibrated `Camera`s.

Conventions (docs/conventions.md): pixel (0, 0) is the centre of the top-left pixel, so pixel centres
sit at integer coordinates and a pixel is covered when its centre lies inside the projected triangle.
Vertices are projected with lens distortion; triangle edges stay straight in the distorted image, which
is accurate to well under a pixel for the small triangles of a hand at working resolution.

Depth is the camera-frame z in metres (not the distance along the ray). Barycentrics are perspective
correct: 1/z is interpolated linearly in the image, so they weight the triangle's 3D corners.

Why fragments instead of a per-triangle loop: a Python loop over a few thousand triangles and eight
views costs ~10 us per triangle before any pixel is touched (~0.3 s per frame). Instead every
triangle's bounding box is expanded into its rows in one vectorised pass (np.repeat), the
covered span of every bounding-box row is solved from the edge functions, so only covered pixels are
generated; the nearest fragment per pixel then wins a scatter-max of 1/depth (np.maximum.at). At 320 px this
is a few ms per view for a hand, a forearm and an object.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import project_points

# Above this many candidate pixels the triangles are processed in batches (bounded memory).
_MAX_CANDIDATES = 1_500_000


@dataclass(frozen=True)
class Fragments:
    """The nearest surface per pixel of one view.

    Attributes:
        face_ids: (H, W) int32 index of the visible face, -1 where no face covers the pixel.
        depth_m: (H, W) float32 camera-frame z of the visible surface, metres; +inf on background.
        bary: (H, W, 3) float32 perspective-correct barycentric weights of the face's three corners
            (sum to 1 on covered pixels, 0 on background), or None when not requested.
    """

    face_ids: np.ndarray
    depth_m: np.ndarray
    bary: np.ndarray | None

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool, True where a face is visible."""
        return self.face_ids >= 0


def _check_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be integer indices of shape (F, 3), got {faces.dtype} {faces.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"faces index vertices outside 0..{len(vertices) - 1}")
    return vertices, faces.astype(np.int64, copy=False)


def _min3(a: np.ndarray) -> np.ndarray:
    """Row minimum of an (N, 3) array (elementwise minimum of the columns: ~5x faster than .min(axis=1))."""
    return np.minimum(np.minimum(a[:, 0], a[:, 1]), a[:, 2])


def _max3(a: np.ndarray) -> np.ndarray:
    """Row maximum of an (N, 3) array."""
    return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])


def _triangle_setup(pixels: np.ndarray, depth_m: np.ndarray, faces: np.ndarray, width: int, height: int,
                    near_m: float, cull: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-face bounding boxes and barycentric plane coefficients for the faces that can cover a pixel.

    `cull` (F,) bool marks faces to drop when they show their back (faces are counter-clockwise seen
    from outside; with the image's y axis pointing down a front face has negative signed area).

    Returns arrays over the kept faces K: ids (K,), x0, y0, bw, bh (K,) int64 boxes, coef (K, 2, 3) so
    that b_i = coef[i, 0] * x + coef[i, 1] * y + coef[i, 2] for corners i = 0, 1, inv_z (K, 3) = 1/z.
    """
    p = pixels[faces]  # (F, 3, 2)
    z = depth_m[faces]  # (F, 3)
    x, y = p[..., 0], p[..., 1]
    x0 = np.ceil(_min3(x))
    x1 = np.floor(_max3(x))
    y0 = np.ceil(_min3(y))
    y1 = np.floor(_max3(y))
    x0 = np.maximum(x0, 0)
    y0 = np.maximum(y0, 0)
    x1 = np.minimum(x1, width - 1)
    y1 = np.minimum(y1, height - 1)
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    keep = (_min3(z) > near_m) & (x1 >= x0) & (y1 >= y0) & (np.abs(area) > 1e-9)
    if cull is not None:
        keep &= ~(np.asarray(cull, bool) & (area > 0))
    ids = np.flatnonzero(keep)
    x, y, area = x[ids], y[ids], area[ids]
    # b0 is the signed area of (p, v1, v2) over the face's area; likewise b1 with (v0, p, v2).
    coef = np.empty((len(ids), 2, 3))
    coef[:, 0, 0] = (y[:, 1] - y[:, 2]) / area
    coef[:, 0, 1] = (x[:, 2] - x[:, 1]) / area
    coef[:, 0, 2] = (x[:, 1] * y[:, 2] - x[:, 2] * y[:, 1]) / area
    coef[:, 1, 0] = (y[:, 2] - y[:, 0]) / area
    coef[:, 1, 1] = (x[:, 0] - x[:, 2]) / area
    coef[:, 1, 2] = (x[:, 2] * y[:, 0] - x[:, 0] * y[:, 2]) / area
    return {
        "ids": ids,
        "x0": x0[ids].astype(np.int64),
        "y0": y0[ids].astype(np.int64),
        "bw": (x1[ids] - x0[ids] + 1).astype(np.int64),
        "bh": (y1[ids] - y0[ids] + 1).astype(np.int64),
        "coef": coef,
        "inv_z": 1.0 / z[ids],
    }


def _batches(counts: np.ndarray) -> list[slice]:
    """Split faces into consecutive slices whose candidate-pixel counts stay under _MAX_CANDIDATES."""
    if counts.sum() <= _MAX_CANDIDATES:
        return [slice(0, len(counts))]
    cum = np.cumsum(counts)
    slices, start = [], 0
    while start < len(counts):
        base = cum[start - 1] if start else 0
        stop = max(int(np.searchsorted(cum, base + _MAX_CANDIDATES, side="right")), start + 1)
        slices.append(slice(start, stop))
        start = stop
    return slices


def _fragments(setup: dict[str, np.ndarray], batch: slice, width: int,
               eps: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All covered (pixel, face) pairs of a batch of faces.

    Faces are first expanded into their bounding-box rows; each row's covered span [xs, xe] follows
    from the three edge inequalities b_i(x, y) >= 0 (linear in x), so only pixels inside the triangle
    are generated: a long diagonal forearm triangle costs its area, not its bounding box.

    Returns pixel index y * W + x (M,) int64, face index into the setup arrays (M,) int64, b0, b1 (M,)
    screen-space barycentrics and inv_z (M,) interpolated 1/depth.
    """
    ids = np.arange(batch.start, batch.stop)
    bh = setup["bh"][batch]
    row_face = np.repeat(ids, bh)
    row_start = np.cumsum(bh) - bh
    py_row = (setup["y0"][row_face] + np.arange(int(bh.sum())) - np.repeat(row_start, bh)).astype(np.float64)
    coef = setup["coef"][row_face]  # (R, 2, 3)
    a = np.stack([coef[:, 0, 0], coef[:, 1, 0], -coef[:, 0, 0] - coef[:, 1, 0]], axis=1)  # (R, 3) d b_i / dx
    rest = np.stack([coef[:, 0, 1] * py_row + coef[:, 0, 2], coef[:, 1, 1] * py_row + coef[:, 1, 2]], axis=1)
    rest = np.concatenate([rest, 1.0 - rest.sum(axis=1, keepdims=True)], axis=1)  # b_i at x = 0
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = (-eps - rest) / a  # b_i >= -eps  <=>  x >= bound (a > 0) or x <= bound (a < 0)
    never = (a == 0) & (rest < -eps)
    lower = _max3(np.where(a > 0, bound, -np.inf))
    upper = _min3(np.where(a < 0, bound, np.inf))
    lower = np.where(never[:, 0] | never[:, 1] | never[:, 2], np.inf, lower)
    xs = np.maximum(np.ceil(lower - 1e-7), setup["x0"][row_face])
    xe = np.minimum(np.floor(upper + 1e-7), setup["x0"][row_face] + setup["bw"][row_face] - 1)
    span = np.clip(xe - xs + 1, 0, None).astype(np.int64)
    pix_row = np.repeat(np.arange(len(span)), span)
    offset = np.arange(int(span.sum())) - np.repeat(np.cumsum(span) - span, span)
    local_face = row_face[pix_row]
    px = xs.astype(np.int64)[pix_row] + offset
    py = py_row[pix_row]
    c = coef[pix_row]
    b0 = c[:, 0, 0] * px + c[:, 0, 1] * py + c[:, 0, 2]
    b1 = c[:, 1, 0] * px + c[:, 1, 1] * py + c[:, 1, 2]
    b2 = 1.0 - b0 - b1
    inside = (b0 >= -eps) & (b1 >= -eps) & (b2 >= -eps)  # drops the few pixels of the 1e-7 slack
    local_face, px, py, b0, b1, b2 = (v[inside] for v in (local_face, px, py, b0, b1, b2))
    iz = setup["inv_z"][local_face]
    inv_z = b0 * iz[:, 0] + b1 * iz[:, 1] + b2 * iz[:, 2]
    return py.astype(np.int64) * width + px, local_face, b0, b1, inv_z


def rasterize_projected(pixels: np.ndarray, depth_m: np.ndarray, faces: np.ndarray, width: int, height: int,
                        *, with_bary: bool = True, near_m: float = 1e-3, cull: np.ndarray | None = None
                        ) -> Fragments:
    """Rasterize a mesh whose vertices are already projected into one view.

    Args:
        pixels: (V, 2) float pixel coordinates of the vertices (distorted, pixel-centre convention).
        depth_m: (V,) float camera-frame z of the vertices, metres.
        faces: (F, 3) int vertex indices.
        width, height: image size, pixels.
        with_bary: also return perspective-correct barycentrics.
        near_m: faces with any corner closer than this (or behind the camera) are skipped.
        cull: (F,) bool, faces that may be skipped when seen from behind (closed meshes), or None.
    Returns:
        The nearest face per pixel (`Fragments`).
    """
    faces = np.asarray(faces, dtype=np.int64)
    n_pix = width * height
    face_ids = np.full(n_pix, -1, dtype=np.int32)
    depth_out = np.full(n_pix, np.inf, dtype=np.float32)
    bary_out = np.zeros((n_pix, 3), dtype=np.float32) if with_bary else None
    best_inv_z = np.zeros(n_pix)  # 1 / depth of the nearest fragment so far (0 = none)
    chosen = np.full(n_pix, -1, dtype=np.int64)
    setup = _triangle_setup(np.asarray(pixels, np.float64), np.asarray(depth_m, np.float64), faces,
                            width, height, near_m, cull)
    for batch in _batches(setup["bw"] * setup["bh"]):
        pix, local_face, b0, b1, inv_z = _fragments(setup, batch, width)
        if not len(pix):
            continue
        # Nearest fragment per pixel: a scatter-max of 1/z (ufunc.at is several times faster than a
        # lexsort on (pixel, depth)), then one winning fragment per pixel (ties: any one of them).
        np.maximum.at(best_inv_z, pix, inv_z)
        win = np.flatnonzero(inv_z == best_inv_z[pix])
        chosen[:] = -1
        chosen[pix[win]] = win
        pix_w = np.flatnonzero(chosen >= 0)
        win = chosen[pix_w]
        face_w = local_face[win]
        face_ids[pix_w] = setup["ids"][face_w]
        depth_out[pix_w] = 1.0 / inv_z[win]
        if bary_out is not None:
            iz = setup["inv_z"][face_w]  # (M, 3)
            b = np.stack([b0[win], b1[win], 1.0 - b0[win] - b1[win]], axis=1)
            b = np.clip(b, 0.0, None) * iz
            bary_out[pix_w] = b / b.sum(axis=1, keepdims=True)
    return Fragments(
        face_ids=face_ids.reshape(height, width),
        depth_m=depth_out.reshape(height, width),
        bary=None if bary_out is None else bary_out.reshape(height, width, 3),
    )


def rasterize(vertices_world: np.ndarray, faces: np.ndarray, cameras: list[Camera], *,
              with_bary: bool = True, near_m: float = 1e-3) -> list[Fragments]:
    """Rasterize one mesh into every camera.

    Args:
        vertices_world: (V, 3) float, metres, world frame.
        faces: (F, 3) int vertex indices.
        cameras: the C views; each output has that camera's (height, width).
        with_bary: also return perspective-correct barycentrics.
        near_m: faces with a corner closer than this to a camera are skipped in that view.
    Returns:
        C `Fragments`, in camera order.
    """
    vertices, faces = _check_mesh(vertices_world, faces)
    pixels, depth = project_points(vertices, cameras)  # (C, V, 2), (C, V)
    return [rasterize_projected(pixels[c], depth[c], faces, cam.width, cam.height, with_bary=with_bary,
                                near_m=near_m) for c, cam in enumerate(cameras)]


def coverage_mask(pixels: np.ndarray, depth_m: np.ndarray, faces: np.ndarray, width: int, height: int, *,
                  near_m: float = 1e-3) -> np.ndarray:
    """(H, W) bool: pixels covered by any face (no depth test: cheaper than `rasterize_projected`)."""
    setup = _triangle_setup(np.asarray(pixels, np.float64), np.asarray(depth_m, np.float64),
                            np.asarray(faces, dtype=np.int64), width, height, near_m)
    mask = np.zeros(width * height, dtype=bool)
    for batch in _batches(setup["bw"] * setup["bh"]):
        pix = _fragments(setup, batch, width)[0]
        mask[pix] = True
    return mask.reshape(height, width)


def model_mask(vertices_world: np.ndarray, faces: np.ndarray, camera: Camera) -> np.ndarray:
    """Silhouette of a mesh in one view.

    Args:
        vertices_world: (V, 3) float, metres, world frame.
        faces: (F, 3) int vertex indices.
        camera: the view.
    Returns:
        (camera.height, camera.width) bool, True where the mesh covers the pixel centre.
    """
    vertices, faces = _check_mesh(vertices_world, faces)
    pixels, depth = project_points(vertices, [camera])
    return coverage_mask(pixels[0], depth[0], faces, camera.width, camera.height)
