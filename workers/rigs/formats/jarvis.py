"""JARVIS (JARVIS-HybridNet / AcquisitionTool) per-camera YAML: OpenCV FileStorage in MATLAB's convention.

PATH: the folder of `<camera name>.yaml` files (calib_params/<set>/). Keys: `intrinsicMatrix` (3x3, the
TRANSPOSE of OpenCV's K: [[fx, 0, 0], [skew, fy, 0], [cx, cy, 1]], MATLAB's row-vector convention),
`distortionCoefficients` (1x5 OpenCV k1 k2 p1 p2 k3), `R` (3x3, the TRANSPOSE of the world -> camera
rotation: MATLAB maps row vectors, x_cam = x_world R + T) and `T` (1x3, world -> camera). JARVIS projects
with [X 1] [R; T] intrinsicMatrix, i.e. OpenCV's K (R X + T) after transposing. JARVIS's calibration
takes the board's square size in millimetres, hence DEFAULT_UNIT. No image size is stored: pass one.
MATLAB's pixel origin is the top-left pixel's centre at (1, 1); JARVIS's exported K already uses
OpenCV's 0-based centres (its calibration runs in OpenCV), so no half/whole-pixel shift is applied.
"""

from __future__ import annotations

from pathlib import Path

from workers.rigs.formats.common import FormatError, RawCamera, as_matrix, read_camera_files
from workers.rigs.formats.opencv_yaml import Storage

DEFAULT_UNIT = "mm"
SUFFIXES = (".yaml", ".yml")


def read_file(path: Path) -> RawCamera:
    fs = Storage(path)
    name = Path(path).stem
    where = f"{path}: camera {name!r}"
    values = {key: fs.mat(key) for key in ("intrinsicMatrix", "distortionCoefficients", "R", "T")}
    missing = [k for k, v in values.items() if v is None]
    if missing:
        raise FormatError(f"{where}: missing field(s) {missing}")
    K_matlab = as_matrix(values["intrinsicMatrix"], (3, 3), where, "intrinsicMatrix")
    if abs(K_matlab[0, 2]) > 1e-9 or abs(K_matlab[1, 2]) > 1e-9 or abs(K_matlab[2, 2] - 1) > 1e-9:
        raise FormatError(f"{where}: field 'intrinsicMatrix' is not in MATLAB's transposed layout "
                          "[[fx, 0, 0], [s, fy, 0], [cx, cy, 1]] (is it already OpenCV's K? use --from opencv)")
    return RawCamera(name=name, K=K_matlab.T, dist=values["distortionCoefficients"].ravel(),
                     R=as_matrix(values["R"], (3, 3), where, "R").T, t=as_matrix(values["T"], (3,), where, "T"))


def read(path: Path) -> tuple[list[RawCamera], list[str]]:
    """Every camera file of the folder, sorted by name (or the single file `path`)."""
    return read_camera_files(path, SUFFIXES, read_file)
