"""What every format reader returns, and the checks that turn it into handloop cameras.

A reader only parses: it returns `RawCamera`s in the file's own length unit, already in handloop's
conventions otherwise (R world -> camera, OpenCV pixel centres, K in pixels). `build_rig` then applies
the unit, fills missing image sizes and refuses values that cannot be right, naming the camera and field.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from workers.capture.schema import ID_PATTERN
from workers.geometry.camera import CalibrationError, Camera
from workers.geometry.rotation import axis_angle_to_matrix
from workers.rigs.extent import RigExtent, rig_extent

UNITS_TO_M: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
# OpenCV's coefficient order beyond k1 k2 p1 p2 k3, and the model each group belongs to.
_EXTRA_COEFFICIENTS = ("k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")
ORTHONORMAL_TOL = 1e-6
TYPICAL_DISTANCE_M = 1.0  # a hand-capture camera's usual distance to the hand
# A hand-capture rig: cameras span 5 cm..30 m, and where the optical axes meet, each camera is this far from that point.
MIN_SPAN_M, MAX_SPAN_M = 0.05, 30.0
MIN_DISTANCE_M, MAX_DISTANCE_M = 0.2, 8.0
MAX_FOV_DEG = 170.0  # wider than this is a fisheye or a focal length in millimetres, not pixels


class FormatError(CalibrationError):
    """A calibration file in another toolchain's format cannot be converted; names file, camera and field."""


@dataclass
class RawCamera:
    """One camera as a format reader found it.

    Attributes:
        name: camera name (must be a capture id, see docs/capture-format.md).
        K: (3, 3) intrinsics, pixels, OpenCV pixel-centre convention.
        dist: OpenCV coefficients in OpenCV's order (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [tau_x tau_y]]]]).
        R: (3, 3) rotation world -> camera (any matrix: `build_rig` checks it).
        t: (3,) translation world -> camera, in the file's length unit.
        width, height: image size in pixels, or None when the format does not store it.
        model: the distortion model's name as the format calls it, for messages ("standard", "OPENCV", ...).
        supported: False when the format names a distortion model handloop cannot represent (fisheye, ...).
    """

    name: str
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int | None = None
    height: int | None = None
    model: str = "opencv"
    supported: bool = True


@dataclass
class Conversion:
    """A converted rig and what the user should know about it.

    Attributes:
        cameras: handloop cameras, in the file's order.
        span_m: largest distance between two camera centres, metres.
        extent: the span and each camera's distance to the rig's centre, metres.
        notes: non-fatal remarks (a world frame on one camera, dropped all-zero coefficients, ...).
    """

    cameras: list[Camera]
    span_m: float
    extent: RigExtent
    notes: list[str] = field(default_factory=list)


def read_camera_files(path: Path, suffixes: tuple[str, ...], read_file: Callable[[Path], RawCamera]
                      ) -> tuple[list[RawCamera], list[str]]:
    """Formats with one file per camera: every such file of the folder `path`, sorted by name (or the single
    file `path`), read by `read_file`; no notes."""
    path = Path(path)
    if path.is_file():
        return [read_file(path)], []
    if not path.is_dir():
        raise FormatError(f"{path}: not found")
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in suffixes and not p.name.startswith("."))
    if not files:
        raise FormatError(f"{path}: no {'/'.join(suffixes)} camera files")
    return [read_file(p) for p in files], []


def as_matrix(value: object, shape: tuple[int, ...], where: str, field_name: str) -> np.ndarray:
    """`value` as a float64 array of `shape` (a flat list of the right size is reshaped); FormatError otherwise."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise FormatError(f"{where}: field '{field_name}' is not a numeric array") from None
    if array.size != math.prod(shape):
        raise FormatError(f"{where}: field '{field_name}' must hold {math.prod(shape)} numbers {shape}, "
                          f"got shape {array.shape}")
    array = array.reshape(shape)
    if not np.all(np.isfinite(array)):
        raise FormatError(f"{where}: field '{field_name}' contains non-finite numbers")
    return array


def as_vector(value: object, where: str, field_name: str) -> np.ndarray:
    """`value` as a flat float64 array of any length; FormatError for non-numbers and non-finite values."""
    try:
        array = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise FormatError(f"{where}: field '{field_name}' is not a list of numbers") from None
    if not np.all(np.isfinite(array)):
        raise FormatError(f"{where}: field '{field_name}' contains non-finite numbers")
    return array


def rotation_field(value: object, where: str, field_name: str) -> np.ndarray:
    """A rotation stored either as a 3x3 matrix or as a 3-vector (Rodrigues): the (3, 3) matrix."""
    array = np.asarray(value, dtype=np.float64) if value is not None else np.zeros(0)
    if array.size == 3:
        return axis_angle_to_matrix(as_matrix(array, (3,), where, field_name))
    return as_matrix(array, (3, 3), where, field_name)


def _check_rotation(R: np.ndarray, where: str) -> None:
    error = float(np.abs(R @ R.T - np.eye(3)).max())
    if error > ORTHONORMAL_TOL:
        raise FormatError(f"{where}: field 'R' is not orthonormal (|R R^T - I| = {error:.3g}); a rotation "
                          "matrix is expected (scaled, sheared or a projection matrix?)")
    if np.linalg.det(R) < 0:
        raise FormatError(f"{where}: field 'R' has determinant -1 (a reflection): the axes are left-handed or "
                          "one axis is flipped")


def _five_coefficients(raw: RawCamera, where: str, notes: list[str]) -> np.ndarray:
    dist = np.asarray(raw.dist, dtype=np.float64).ravel()
    if not raw.supported:
        raise FormatError(f"{where}: distortion model {raw.model!r} is not supported: handloop's cameras use "
                          "OpenCV's k1 k2 p1 p2 k3 (undistort the images or recalibrate with that model)")
    if dist.size not in (0, 4, 5, 8, 12, 14):
        raise FormatError(f"{where}: field 'dist' has {dist.size} coefficients; OpenCV models have 4, 5, 8, 12 "
                          "or 14")
    if not np.all(np.isfinite(dist)):
        raise FormatError(f"{where}: field 'dist' contains non-finite numbers")
    extra = dist[5:]
    used = [name for name, v in zip(_EXTRA_COEFFICIENTS, extra, strict=False) if v != 0.0]
    if used:
        model = ("tilted" if any(n.startswith("tau") for n in used) else
                 "thin prism" if any(n.startswith("s") for n in used) else "rational")
        raise FormatError(f"{where}: distortion model {model!r} ({', '.join(used)} non-zero) is not supported: "
                          "handloop's cameras use OpenCV's k1 k2 p1 p2 k3")
    if extra.size:
        notes.append(f"camera {raw.name!r}: {extra.size} extra distortion coefficients are all zero (dropped)")
    out = np.zeros(5)
    out[:min(5, dist.size)] = dist[:5]
    return out


def implausible(extent: RigExtent) -> str | None:
    """Why a rig of this extent (metres) is no hand-capture rig, or None when it could be one."""
    if extent.span > 0.0 and not MIN_SPAN_M <= extent.span <= MAX_SPAN_M:
        return f"the cameras span {extent.span:.4g} m, outside {MIN_SPAN_M}..{MAX_SPAN_M} m"
    if extent.centre_is_focus:
        far = {n: d for n, d in extent.distances.items() if not MIN_DISTANCE_M <= d <= MAX_DISTANCE_M}
        if far:
            return ("camera(s) " + ", ".join(f"{n} {d:.4g} m" for n, d in far.items()) + " from the point the "
                    f"cameras look at (the hand), outside {MIN_DISTANCE_M}..{MAX_DISTANCE_M} m")
    return None


def describe_unit(unit: str, scale: float | None) -> str:
    """How the file's lengths were read, for messages: "mm" or "--scale 0.044 m per file unit"."""
    return f"--scale {scale:.6g} m per file unit" if scale is not None else unit


UNKNOWN_SCALE_HINT = ("or, when the file's unit is unknown, --unknown-scale (converted as read; after `capture "
                      "assemble`, `handloop calibration check` measures the scale from the hand)")


def check_units(extent: RigExtent, unit: str, source: str, scale: float | None = None) -> None:
    """Refuse a rig (`extent` in metres, read in `unit`, or with `scale` metres per file unit) whose size does not fit
    a hand-capture rig: the length unit was read wrong. The hint names only the units that give a plausible rig
    (closest to cameras ~1 m from the hand first) and always --scale, for files in board squares."""
    problem = implausible(extent)
    if problem is None:
        return
    per_unit = scale if scale is not None else UNITS_TO_M[unit]
    candidates = {u: extent.scaled(s / per_unit) for u, s in UNITS_TO_M.items() if scale is not None or u != unit}
    fits = sorted((u for u, e in candidates.items() if implausible(e) is None),
                  key=lambda u: abs(math.log(np.median(list(candidates[u].distances.values())) / TYPICAL_DISTANCE_M)))
    units = " or ".join(f"--units {u} (a {candidates[u].span:.3g} m rig, cameras "
                        f"{min(candidates[u].distances.values()):.3g}..{max(candidates[u].distances.values()):.3g} m "
                        "from its centre)" for u in fits)
    metres_per_unit = ("--scale METRES_PER_FILE_UNIT (e.g. the calibration board's square size in metres if the file "
                       "is in board squares)")
    hint = (f"pass {units}, or {metres_per_unit}, {UNKNOWN_SCALE_HINT}" if fits else
            f"no unit ({', '.join(UNITS_TO_M)}) gives a plausible rig: pass {metres_per_unit}, {UNKNOWN_SCALE_HINT}")
    raise FormatError(f"{source}: read in {describe_unit(unit, scale)}, {problem} for a hand-capture rig: the length "
                      f"unit is wrong; {hint}")


def build_rig(raws: list[RawCamera], *, unit: str, source: str, image_size: tuple[int, int] | None = None,
              notes: list[str] | None = None, scale: float | None = None, unknown_scale: bool = False) -> Conversion:
    """Validate raw cameras and convert them to handloop cameras in metres.

    Args:
        raws: from a format reader, translations in `unit`.
        unit: one of UNITS_TO_M (m, cm, mm, in): the file's length unit.
        scale: metres per file unit (e.g. a board square's size in metres); replaces `unit` when given.
        unknown_scale: the file's unit is unknown: a rig of implausible size is kept (with a note) instead of
            refused, for `handloop calibration check` to measure the scale from the hand.
        source: the file, for messages.
        image_size: (width, height) for cameras whose format stores no size.
        notes: the reader's remarks, extended here.
    Raises:
        FormatError: naming the camera and field (rotation, focal length, distortion, size, units, names).
    """
    if unit not in UNITS_TO_M:
        raise FormatError(f"{source}: unknown unit {unit!r}; use one of {list(UNITS_TO_M)}")
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise FormatError(f"{source}: --scale must be a positive number of metres per file unit, not {scale!r}")
    if not raws:
        raise FormatError(f"{source}: no cameras found")
    notes = list(notes or [])
    names = [r.name for r in raws]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise FormatError(f"{source}: camera name(s) {repeated} appear more than once")
    metres_per_unit = scale if scale is not None else UNITS_TO_M[unit]
    cameras = []
    for raw in raws:
        where = f"{source}: camera {raw.name!r}"
        if not ID_PATTERN.match(raw.name):
            raise FormatError(f"{where}: field 'name' must match {ID_PATTERN.pattern} to name the camera's image "
                              "folders (rename it in the file)")
        width, height = raw.width, raw.height
        if width is None or height is None:
            if image_size is None:
                raise FormatError(f"{where}: the file stores no image size (fields 'width', 'height'); pass "
                                  "--image-size WIDTHxHEIGHT")
            width, height = image_size
        dist = _five_coefficients(raw, where, notes)
        K = as_matrix(raw.K, (3, 3), where, "K")
        R = as_matrix(raw.R, (3, 3), where, "R")
        t = as_matrix(raw.t, (3,), where, "t") * metres_per_unit
        _check_rotation(R, where)
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise FormatError(f"{where}: field 'K' has non-positive focal lengths ({K[0, 0]:.6g}, {K[1, 1]:.6g})")
        fov_deg = math.degrees(2 * math.atan(width / (2 * K[0, 0])))
        if fov_deg > MAX_FOV_DEG:
            raise FormatError(f"{where}: field 'K' focal length {K[0, 0]:.6g} px gives a {fov_deg:.1f} degree field "
                              f"of view on a {width} px image: a focal length in millimetres or normalised "
                              "units, not pixels?")
        if not (-width <= K[0, 2] <= 2 * width and -height <= K[1, 2] <= 2 * height):
            raise FormatError(f"{where}: field 'K' principal point ({K[0, 2]:.6g}, {K[1, 2]:.6g}) is far outside "
                              f"the {width}x{height} image (transposed K, or the image size is wrong?)")
        try:
            cameras.append(Camera(raw.name, int(width), int(height), K, dist, R, t))
        except CalibrationError as exc:
            raise FormatError(f"{source}: {exc}") from None
    extent = rig_extent(cameras)
    if unknown_scale:
        problem = implausible(extent)
        notes.append(f"the unit is unknown (--unknown-scale): read in {describe_unit(unit, scale)}"
                     + (f", {problem}" if problem else "") + "; after `handloop capture assemble`, `handloop "
                     "calibration check CAPTURE` measures the scale from the hand and gives the --scale to use")
    else:
        check_units(extent, unit, source, scale)
    for cam in cameras:
        if np.allclose(cam.R, np.eye(3), atol=1e-9) and np.allclose(cam.t, 0.0, atol=1e-12):
            notes.append(f"camera {cam.name!r}: R = I and t = 0, so the world frame is this camera's frame "
                         "(z forward, y down), not a rig-centred frame with z up")
    return Conversion(cameras=cameras, span_m=extent.span, extent=extent, notes=notes)
