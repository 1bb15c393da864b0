"""caliscope's `camera_array.toml` (caliscope >= 0.6, `CameraArray.to_toml`) and its older `config.toml`.

camera_array.toml: one table per camera, `[cameras.0]`, `[cameras.1]`, ..., with `cam_id` (integer), `size` =
[width, height] pixels, `matrix` (3x3 K, pixels), `distortions` (OpenCV k1 k2 p1 p2 k3; fisheye k1..k4 when
`fisheye = true`), `rotation` and `translation` world -> camera (caliscope projects with [R | t]; it calls them
"camera relative to world"): the rotation a Rodrigues vector (radians), or a 3x3 matrix in files from older
versions; plus workspace fields (`rotation_count`, `error`, `exposure`, `grid_count`, `ignore`), ignored.
config.toml (older caliscope): the same fields in top-level `[cam_0]`, `[cam_1]`, ... tables (rotation usually a
3x3 matrix) beside `[charuco]`, `[capture_volume]` and settings, which are ignored.
Cameras have no name: they are called `cam_<cam_id>`, as caliscope's own aniposelib export calls them. A camera
with `ignore = true` is left out (with a note); one without `rotation`/`translation` was never posed and is
refused. Units: metres (caliscope scales its board to metres). World frame: the origin set on a board in
caliscope's GUI, else the anchor camera's. Pixel convention: OpenCV's. Read with tomllib.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from workers.rigs.formats import tomlfile
from workers.rigs.formats.common import FormatError, RawCamera, as_matrix, as_vector, rotation_field

DEFAULT_UNIT = "m"
_KEYS = ("size", "matrix", "distortions")
_CONFIG_TABLE = re.compile(r"cam_\d+")


def camera_tables(data: dict[str, Any]) -> dict[str, dict[str, Any]] | None:
    """{where: table} of caliscope camera tables (camera_array.toml's [cameras.N] or config.toml's [cam_N] with a
    `cam_id`), or None when `data` has neither."""
    cameras = data.get("cameras")
    if isinstance(cameras, dict) and cameras and all(isinstance(v, dict) for v in cameras.values()):
        return {f"[cameras.{k}]": v for k, v in cameras.items()}
    tables = {f"[{k}]": v for k, v in data.items()
              if _CONFIG_TABLE.fullmatch(k) and isinstance(v, dict) and "cam_id" in v and "name" not in v}
    return tables or None


def read(path: Path) -> tuple[list[RawCamera], list[str]]:
    """The posed, not ignored cameras of a caliscope camera_array.toml or config.toml, in cam_id order;
    translations in metres."""
    tables = camera_tables(tomlfile.load(path))
    if tables is None:
        raise FormatError(f"{path}: no caliscope camera tables ([cameras.0], ... in camera_array.toml, or [cam_0], "
                          "... with a 'cam_id' in config.toml)")
    raws, notes = [], []
    for key, table in tables.items():
        where = f"{path}: {key}"
        if "cam_id" not in table:
            raise FormatError(f"{where}: missing field 'cam_id'")
        try:
            cam_id = int(table["cam_id"])
        except (TypeError, ValueError):
            raise FormatError(f"{where}: field 'cam_id' must be an integer, not {table['cam_id']!r}") from None
        name = f"cam_{cam_id}"
        if table.get("ignore", False):
            notes.append(f"camera {name!r}: ignore = true in the file (left out)")
            continue
        missing = [k for k in _KEYS if k not in table]
        if missing:
            raise FormatError(f"{where}: missing field(s) {missing}")
        where = f"{path}: camera {name!r}"
        unposed = [k for k in ("rotation", "translation") if table.get(k) in (None, "null")]
        if unposed:
            raise FormatError(f"{where}: no {' or '.join(repr(k) for k in unposed)}: caliscope never posed this "
                              "camera (finish the extrinsic calibration, or set ignore = true for it)")
        width, height = (int(v) for v in as_matrix(table["size"], (2,), where, "size"))
        fisheye = bool(table.get("fisheye", False))
        raws.append((cam_id, RawCamera(
            name=name, K=as_matrix(table["matrix"], (3, 3), where, "matrix"),
            dist=as_vector(table["distortions"], where, "distortions"),
            R=rotation_field(table["rotation"], where, "rotation"),
            t=as_matrix(table["translation"], (3,), where, "translation"),
            width=width, height=height, model="fisheye" if fisheye else "opencv", supported=not fisheye)))
    return [raw for _, raw in sorted(raws, key=lambda r: r[0])], notes
