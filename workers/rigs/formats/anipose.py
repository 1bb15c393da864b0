"""Anipose / aniposelib `calibration.toml` (also sleap-anipose; Pose2Sim's own writer: see pose2sim.py).

Layout (aniposelib `CameraGroup.dump`): one table per camera (`[cam_0]`, `[cam_1]`, ...) with `name`,
`size` = [width, height] pixels, `matrix` (3x3 K, pixels), `distortions` (OpenCV k1 k2 p1 p2 k3; four
fisheye coefficients when `fisheye = true`), `rotation` (Rodrigues vector, radians, world -> camera; a 3x3 matrix,
as hand-edited files hold, is read too) and
`translation` (world -> camera, in the calibration board's unit: whatever `square_length` was given in,
often millimetres). A `[metadata]` table is ignored. Pixel convention: OpenCV's. World frame: the one the
calibration chose (aniposelib: the first camera's, unless the rig was re-centred). Read with tomllib.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from workers.rigs.formats import tomlfile
from workers.rigs.formats.common import FormatError, RawCamera, as_matrix, as_vector, rotation_field

DEFAULT_UNIT = "m"
_KEYS = ("name", "size", "matrix", "distortions", "rotation", "translation")


def read(path: Path) -> tuple[list[RawCamera], list[str]]:
    """The cameras of an aniposelib calibration.toml, in table order; translations in the file's unit."""
    return read_tables(path, tomlfile.load(path)), []


def read_tables(path: Path, data: dict[str, Any]) -> list[RawCamera]:
    """The aniposelib camera tables of a parsed TOML file (every table but [metadata])."""
    raws = []
    for key, table in data.items():
        if key == "metadata" or not isinstance(table, dict):
            continue
        missing = [k for k in _KEYS if k not in table]
        where = f"{path}: [{key}]"
        if missing:
            raise FormatError(f"{where}: missing field(s) {missing}")
        name = str(table["name"])
        where = f"{path}: camera {name!r}"
        width, height = (int(v) for v in as_matrix(table["size"], (2,), where, "size"))
        fisheye = bool(table.get("fisheye", False))
        raws.append(RawCamera(
            name=name, K=as_matrix(table["matrix"], (3, 3), where, "matrix"),
            dist=as_vector(table["distortions"], where, "distortions"),
            R=rotation_field(table["rotation"], where, "rotation"),
            t=as_matrix(table["translation"], (3,), where, "translation"),
            width=width, height=height, model="fisheye" if fisheye else "opencv", supported=not fisheye))
    return raws
