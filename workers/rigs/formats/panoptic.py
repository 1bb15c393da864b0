"""CMU Panoptic Studio `calibration_<sequence>.json`.

`{"calibDataSource": ..., "cameras": [camera, ...]}`; each camera: `name` (e.g. "00_03", panel_node),
`type` ("vga", "hd", "kinect-color", ...), `resolution` = [width, height] pixels, `K` (3x3, pixels),
`distCoef` (OpenCV k1 k2 p1 p2 k3), `R` (3x3, world -> camera) and `t` (3x1, world -> camera) in
centimetres: Panoptic's world unit is the centimetre, hence DEFAULT_UNIT. World frame: the dome's, y down
(the floor is at y > 0), not z up. `camera_type` keeps one kind of camera (the HD ones, say).
"""

from __future__ import annotations

from pathlib import Path

from workers.rigs.formats import jsonfile
from workers.rigs.formats.common import FormatError, RawCamera, as_matrix, as_vector

DEFAULT_UNIT = "cm"
_KEYS = ("name", "resolution", "K", "distCoef", "R", "t")


def read(path: Path, camera_type: str | None = None) -> tuple[list[RawCamera], list[str]]:
    """The cameras of a Panoptic calibration JSON, in file order (only `camera_type` ones when given)."""
    data = jsonfile.load(path)
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), list):
        raise FormatError(f"{path}: expected an object with a 'cameras' list")
    raws = []
    for i, cam in enumerate(data["cameras"]):
        where = f"{path}: cameras[{i}]"
        if not isinstance(cam, dict):
            raise FormatError(f"{where}: expected an object")
        missing = [k for k in _KEYS if k not in cam]
        if missing:
            raise FormatError(f"{where}: missing field(s) {missing}")
        if camera_type is not None and cam.get("type") != camera_type:
            continue
        name = str(cam["name"])
        where = f"{path}: camera {name!r}"
        width, height = (int(v) for v in as_matrix(cam["resolution"], (2,), where, "resolution"))
        dist = as_vector(cam["distCoef"], where, "distCoef")
        raws.append(RawCamera(name=name, K=as_matrix(cam["K"], (3, 3), where, "K"), dist=dist,
                              R=as_matrix(cam["R"], (3, 3), where, "R"), t=as_matrix(cam["t"], (3,), where, "t"),
                              width=width, height=height))
    if not raws and camera_type is not None:
        raise FormatError(f"{path}: no camera of type {camera_type!r}")
    return raws, []
