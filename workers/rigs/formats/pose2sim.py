"""Pose2Sim's `Calib_*.toml` (Pose2Sim/calibration.py `toml_write`): Anipose's layout, as Pose2Sim writes it.

One table per camera named after the camera (`[cam_01]`, `[int_cam01_img]`, ...) with `name` (the table's
name), `size` = [width, height] pixels written as floats (`[ 1088.0, 1920.0]`), `matrix` (3x3 K, pixels),
`distortions` = four OpenCV coefficients k1 k2 p1 p2 (k3 = 0), `rotation` (Rodrigues vector, radians,
world -> camera), `translation` (world -> camera, metres: Pose2Sim converts its millimetre board sizes and
the Qualisys/Vicon/OpenCap/BioCV files it imports), `fisheye = false`, and a final `[metadata]` table
(`adjusted`, `error`), ignored. World frame: the extrinsic board's (z up when the board lies on the floor) or
the imported system's. Pixel convention: OpenCV's. Pose2Sim reads Anipose's, FreeMoCap's and caliscope's
aniposelib exports unchanged, so the reading is Anipose's.
"""

from __future__ import annotations

from pathlib import Path

from workers.rigs.formats import anipose, tomlfile
from workers.rigs.formats.common import RawCamera

DEFAULT_UNIT = "m"


def read(path: Path) -> tuple[list[RawCamera], list[str]]:
    """The cameras of a Pose2Sim calibration TOML, in table order; translations in the file's unit (metres)."""
    return anipose.read_tables(path, tomlfile.load(path)), []
