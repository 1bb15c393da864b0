"""Fitted meshes as PLY / OBJ files (trimesh), metres, in the frame the caller gives (exports: world)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

MESH_FORMATS = ("ply", "obj")


def write_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write (V, 3) vertices and (F, 3) faces; the suffix of `path` (.ply binary or .obj) picks the format."""
    suffix = path.suffix.lstrip(".").lower()
    if suffix not in MESH_FORMATS:
        raise ValueError(f"mesh format must be one of {MESH_FORMATS}, not {suffix!r}")
    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, np.float64), faces=np.asarray(faces, np.int64),
                           process=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path, file_type=suffix)


def read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices and (F, 3) int64 faces of a PLY or OBJ file, in file order."""
    mesh = trimesh.load(path, process=False, force="mesh")
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
