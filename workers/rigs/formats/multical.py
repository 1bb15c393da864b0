"""multical's `calibration.json`: camera poses relative to one camera, not to a world frame.

`{"cameras": {name: {"model", "image_size": [w, h], "K": 3x3, "dist": [[...]]}}, "camera_poses": {...}}`.
`model` is "standard" (OpenCV k1 k2 p1 p2 k3), "rational", "thin_prism" or "fisheye". A key of
`camera_poses` is either a camera name (the base camera: its pose is the world, normally R = I, T = 0)
or "<camera>_to_<parent>": R, T map points from the parent camera's frame into this camera's frame,
X_cam = R X_parent + T. Chains are composed down to the base, so the world frame is the base camera's
(z forward, y down). Lengths are in the calibration board's unit (multical boards: metres).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workers.rigs.formats import jsonfile
from workers.rigs.formats.common import FormatError, RawCamera, as_matrix, as_vector

DEFAULT_UNIT = "m"
_SUPPORTED_MODELS = ("standard",)


def _pose(entry: object, where: str) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(entry, dict) or "R" not in entry or "T" not in entry:
        raise FormatError(f"{where}: expected an object with fields 'R' and 'T'")
    return as_matrix(entry["R"], (3, 3), where, "R"), as_matrix(entry["T"], (3,), where, "T")


def read(path: Path) -> tuple[list[RawCamera], list[str]]:
    """The cameras of multical's calibration.json with poses composed to the base camera's frame."""
    data = jsonfile.load(path)
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), dict) \
            or not isinstance(data.get("camera_poses"), dict):
        raise FormatError(f"{path}: expected an object with 'cameras' and 'camera_poses' objects")
    cameras, poses = data["cameras"], data["camera_poses"]
    parent: dict[str, str | None] = {}
    relative: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for key, entry in poses.items():
        child, sep, par = key.partition("_to_")
        if child in parent:
            raise FormatError(f"{path}: camera_poses: camera {child!r} has two poses")
        parent[child] = par if sep else None
        relative[child] = _pose(entry, f"{path}: camera_poses[{key!r}]")
    missing = sorted(set(cameras) - set(parent))
    if missing:
        raise FormatError(f"{path}: camera_poses has no pose for camera(s) {missing} ({len(cameras)} cameras, "
                          f"{len(parent)} poses): camera count mismatch")
    unknown = sorted((set(parent) | {p for p in parent.values() if p}) - set(cameras))
    if unknown:
        raise FormatError(f"{path}: camera_poses names camera(s) {unknown} not in 'cameras'")
    roots = [c for c, p in parent.items() if p is None]
    if len(roots) != 1:
        raise FormatError(f"{path}: camera_poses must have exactly one base camera (a key without '_to_'), "
                          f"found {roots}")

    def world_pose(name: str, seen: tuple[str, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
        if name in seen:
            raise FormatError(f"{path}: camera_poses: the chain {' -> '.join((*seen, name))} loops")
        R, T = relative[name]
        if parent[name] is None:
            return R, T
        Rp, Tp = world_pose(parent[name], (*seen, name))
        return R @ Rp, R @ Tp + T  # X_cam = R (Rp X_w + Tp) + T

    raws = []
    notes = [f"{path}: the world frame is base camera {roots[0]!r}'s frame (z forward, y down), as multical "
             "defines it"]
    for name, cam in cameras.items():
        where = f"{path}: camera {name!r}"
        if not isinstance(cam, dict):
            raise FormatError(f"{where}: expected an object")
        for key in ("image_size", "K", "dist"):
            if key not in cam:
                raise FormatError(f"{where}: missing field {key!r}")
        model = str(cam.get("model", "standard"))
        width, height = (int(v) for v in as_matrix(cam["image_size"], (2,), where, "image_size"))
        dist = as_vector(cam["dist"], where, "dist")
        R, T = world_pose(name)
        raws.append(RawCamera(name=name, K=as_matrix(cam["K"], (3, 3), where, "K"), dist=dist, R=R, t=T,
                              width=width, height=height, model=model, supported=model in _SUPPORTED_MODELS))
    return raws, notes
