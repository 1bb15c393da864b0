"""Plain OpenCV FileStorage, one file per camera (YAML or XML), as OpenCV's calibration sample writes it.

PATH: a folder of `<camera name>.yml|.yaml|.xml` files (or one such file). Keys: `camera_matrix` (3x3
K, pixels), `distortion_coefficients` (OpenCV order; 4, 5, 8, 12 or 14 numbers), `image_width`,
`image_height` (pixels); extrinsics world -> camera as `R` (3x3 matrix or 3x1 Rodrigues) or `rvec`,
and `T` or `tvec` (3x1, in the file's unit). The camera name is the file's stem.
"""

from __future__ import annotations

from pathlib import Path

from workers.rigs.formats.common import FormatError, RawCamera, as_matrix, read_camera_files, rotation_field
from workers.rigs.formats.opencv_yaml import Storage

DEFAULT_UNIT = "m"
SUFFIXES = (".yml", ".yaml", ".xml")


def read_file(path: Path, name: str | None = None) -> RawCamera:
    """One camera from one FileStorage file (named after the file unless `name` is given)."""
    fs = Storage(path)
    name = name or Path(path).stem
    where = f"{path}: camera {name!r}"
    K = fs.mat("camera_matrix")
    if K is None:
        raise FormatError(f"{where}: missing field 'camera_matrix'")
    dist = fs.mat("distortion_coefficients")
    rot = fs.mat("R") if fs.has("R") else fs.mat("rvec")
    T = fs.mat("T") if fs.has("T") else fs.mat("tvec")
    if rot is None or T is None:
        raise FormatError(f"{where}: missing extrinsics: fields 'R' (or 'rvec') and 'T' (or 'tvec')")
    width, height = fs.number("image_width"), fs.number("image_height")
    return RawCamera(name=name, K=as_matrix(K, (3, 3), where, "camera_matrix"),
                     dist=[] if dist is None else dist.ravel(), R=rotation_field(rot, where, "R"),
                     t=as_matrix(T, (3,), where, "T"), width=None if width is None else int(width),
                     height=None if height is None else int(height))


def read(path: Path) -> tuple[list[RawCamera], list[str]]:
    """Every camera file of a folder, sorted by name (or the single file `path`)."""
    return read_camera_files(path, SUFFIXES, read_file)
