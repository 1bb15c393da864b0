"""`handloop calibration convert` (other toolchains' calibration files -> calibration.json) and
`handloop calibration check` (a capture's calibration against 2D keypoints). See docs/calibration.md."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import typer

FORMAT_HELP = "anipose|pose2sim|caliscope|easymocap|opencv|panoptic|multical|jarvis|colmap"


def _image_size(value: str | None) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        width, height = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise typer.BadParameter(f"--image-size must look like 2048x1536, not {value!r}") from None
    if not (1 <= width <= 100_000 and 1 <= height <= 100_000):
        raise typer.BadParameter(f"--image-size {value!r} is out of range 1..100000")
    return width, height


def write_atomically(path: Path, text: str) -> None:
    """Write `text` to `path` through a temporary file in the same folder: never a partial file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def register(app: typer.Typer, bench: typer.Typer) -> None:
    calibration = typer.Typer(help="Calibration files: convert other toolchains' formats; check a capture's rig.",
                              no_args_is_help=True)
    app.add_typer(calibration, name="calibration")

    @calibration.command("convert")
    def convert_cmd(
        path: Path = typer.Argument(..., help="The format's file, or the folder (EasyMocap, COLMAP, OpenCV, JARVIS)."),
        from_format: str = typer.Option(..., "--from", help=FORMAT_HELP),
        out: Path = typer.Option(..., "--out", help="handloop calibration.json to write."),
        units: str | None = typer.Option(None, "--units", help="The file's length unit: m, cm, mm or in "
                                                               "(default: the format's usual one)."),
        scale: float | None = typer.Option(None, "--scale", help="Metres per file unit, e.g. the calibration "
                                                                 "board's square size in metres for a file in board "
                                                                 "squares; replaces --units (give one of the two)."),
        unknown_scale: bool = typer.Option(False, "--unknown-scale", help="The file's length unit is unknown (e.g. "
                                           "board squares of unknown size): convert as read; `handloop calibration "
                                           "check` on the assembled capture measures the scale from the hand."),
        image_size: str | None = typer.Option(None, "--image-size", help="WIDTHxHEIGHT for formats that store "
                                                                         "no image size (JARVIS, old EasyMocap)."),
        cameras: int | None = typer.Option(None, "--cameras", min=1, help="Refuse unless the rig has this many."),
        camera_type: str | None = typer.Option(None, "--camera-type", help="Panoptic: keep cameras of this type "
                                                                           "(hd, vga, kinect-color)."),
        geometry_check: bool = typer.Option(True, "--geometry-check/--no-geometry-check",
                                            help="Refuse a camera that does not see what the others look at."),
        force: bool = typer.Option(False, "--force", help="Overwrite --out if it exists."),
    ) -> None:
        """Convert a calibration to handloop's calibration.json (metres, R world -> camera, OpenCV distortion)."""
        from workers.geometry.camera import save_calibration
        from workers.rigs.formats import FORMATS, FormatError, convert, default_unit

        if from_format not in FORMATS:
            raise typer.BadParameter(f"--from must be one of {', '.join(FORMATS)}, not {from_format!r}")
        from workers.rigs.formats.common import UNITS_TO_M, describe_unit

        if units is not None and units not in UNITS_TO_M:
            raise typer.BadParameter(f"--units must be one of {', '.join(UNITS_TO_M)}, not {units!r}")
        if scale is not None and units is not None:
            raise typer.BadParameter("give --units or --scale, not both: --scale is the file unit's size in metres "
                                     "and replaces --units")
        if scale is not None and not (math.isfinite(scale) and scale > 0):
            raise typer.BadParameter(f"--scale must be a positive number of metres per file unit, not {scale!r}")
        if out.exists() and not force:
            typer.echo(f"error: {out} exists; pass --force to overwrite it", err=True)
            raise typer.Exit(code=2)
        options = {"camera_type": camera_type} if from_format == "panoptic" else {}
        if camera_type is not None and from_format != "panoptic":
            raise typer.BadParameter("--camera-type applies to --from panoptic only")
        try:
            conversion = convert(from_format, path, unit=units, scale=scale, unknown_scale=unknown_scale,
                                 image_size=_image_size(image_size),
                                 check_geometry=geometry_check, expect_cameras=cameras, **options)
        except FormatError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        with tempfile.TemporaryDirectory() as tmp:
            save_calibration(conversion.cameras, Path(tmp) / "calibration.json")
            write_atomically(out, (Path(tmp) / "calibration.json").read_text())
        for note in conversion.notes:
            typer.echo(f"note: {note}", err=True)
        span_line, distance_line = conversion.extent.lines()
        typer.echo(f"wrote {out}: {len(conversion.cameras)} cameras ({', '.join(c.name for c in conversion.cameras)}),"
                   f" read in {describe_unit(units or default_unit(from_format), scale)}, {span_line}")
        typer.echo(distance_line)

    @calibration.command("check")
    def check_cmd(
        capture: Path = typer.Argument(..., help="Capture folder."),
        json_out: bool = typer.Option(False, "--json", help="Print the report as one line of JSON (the last line)."),
        source: str = typer.Option("auto", "--keypoints",
                                   help="auto (ground truth, else the detector), ground-truth or detector."),
        sequence: str | None = typer.Option(None, "--sequence", help="Only this sequence."),
        max_frames: int = typer.Option(50, "--max-frames", min=1, max=100_000,
                                       help="Frames used (spread evenly over the capture)."),
    ) -> None:
        """Per camera pair the epipolar agreement of 2D keypoints found without the calibration; the camera that
        explains the disagreement is flagged (turned, moved, swapped names). Exit 1: the calibration disagrees;
        2: the check cannot run or judge anything."""
        from workers.capture import CaptureError
        from workers.rigs.check import CheckError, check_capture, format_report

        if source not in ("auto", "ground-truth", "detector"):
            raise typer.BadParameter(f"--keypoints must be auto, ground-truth or detector, not {source!r}")
        try:
            report = check_capture(capture, source=source, sequence_id=sequence, max_frames=max_frames,
                                   log=lambda line: typer.echo(line, err=True), progress=True)
        except (CaptureError, CheckError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        typer.echo(json.dumps(report.to_dict(), allow_nan=False) if json_out else format_report(report))
        if report.verdict == "not-judged":
            raise typer.Exit(code=2)
        if not report.agrees:
            raise typer.Exit(code=1)
