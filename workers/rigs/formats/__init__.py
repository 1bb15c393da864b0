"""Calibration files of other toolchains -> handloop's calibration.json (docs/calibration.md).

One reader module per format; each docstring states the format's conventions (world frame, units,
rotation direction and representation, pixel origin, distortion models). `convert` reads, applies the
unit, validates (common.build_rig) and checks the rig's geometry (sanity.check_aim).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType

from workers.rigs.formats.common import UNITS_TO_M, Conversion, FormatError, build_rig
from workers.rigs.formats.sniff import mismatch
from workers.rigs.sanity import check_aim

FORMATS = ("anipose", "pose2sim", "caliscope", "easymocap", "opencv", "panoptic", "multical", "jarvis", "colmap")

__all__ = ["FORMATS", "UNITS_TO_M", "Conversion", "FormatError", "convert", "default_unit"]


def _module(fmt: str) -> ModuleType:
    if fmt not in FORMATS:
        raise FormatError(f"unknown calibration format {fmt!r}; known: {', '.join(FORMATS)}")
    return importlib.import_module(f"{__name__}.{fmt}")


def default_unit(fmt: str) -> str:
    """The length unit a format's files normally use (a key of UNITS_TO_M)."""
    return _module(fmt).DEFAULT_UNIT


def convert(fmt: str, path: Path, *, unit: str | None = None, scale: float | None = None, unknown_scale: bool = False,
            image_size: tuple[int, int] | None = None, check_geometry: bool = True, expect_cameras: int | None = None,
            **options: object) -> Conversion:
    """Read a calibration in format `fmt` as handloop cameras (metres, R world -> camera).

    Args:
        fmt: one of FORMATS.
        path: the format's file or folder.
        unit: the file's length unit, a key of UNITS_TO_M (default: the format's usual one, see each module's
            DEFAULT_UNIT).
        scale: metres per file unit (e.g. the calibration board's square size in metres for a file in board
            squares); replaces `unit`, so give one or the other.
        unknown_scale: keep a rig of implausible size (noted) for the calibration check to measure its scale.
        image_size: (width, height) pixels for formats that store none.
        check_geometry: refuse a camera that does not see the point the others look at.
        expect_cameras: refuse a rig with another number of cameras.
        options: format-specific reader options (panoptic: camera_type).
    Raises:
        FormatError: naming the file, the camera and the field at fault; for a file that fails to read and looks
            like another format, naming that format.
    """
    if unit is not None and scale is not None:
        raise FormatError(f"{path}: give the file's unit or a scale, not both (--scale is metres per file unit and "
                          "replaces --units)")

    module = _module(fmt)
    try:
        raws, notes = module.read(Path(path), **options)
    except FormatError as exc:
        other = mismatch(fmt, Path(path))
        if other is None:
            raise
        raise FormatError(f"{other} (read as {fmt}: {str(exc).removeprefix(f'{path}: ')})") from None
    conversion = build_rig(raws, unit=unit or module.DEFAULT_UNIT, source=str(path), image_size=image_size,
                           notes=notes, scale=scale, unknown_scale=unknown_scale)
    if expect_cameras is not None and len(conversion.cameras) != expect_cameras:
        raise FormatError(f"{path}: {len(conversion.cameras)} cameras "
                          f"{[c.name for c in conversion.cameras]}, expected {expect_cameras}: camera count mismatch")
    if check_geometry:
        problems = [r.problem for r in check_aim(conversion.cameras) if r.problem]
        if problems:
            raise FormatError(f"{path}: " + "; ".join(problems) + " (pass --no-geometry-check to convert anyway)")
    return conversion
