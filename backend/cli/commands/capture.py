"""`handloop capture assemble`: a capture from one video or image folder per camera and a calibration."""

from __future__ import annotations

import sys
from pathlib import Path

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    capture = typer.Typer(help="Build captures from a lab's own recordings.", no_args_is_help=True)
    app.add_typer(capture, name="capture")

    @capture.command("assemble")
    def assemble(
        calibration: Path = typer.Option(..., "--calibration", help="handloop calibration.json (see "
                                                                   "`handloop calibration convert`)."),
        out: Path = typer.Option(..., "--out", help="Capture folder to create."),
        videos: Path | None = typer.Option(None, "--videos", help="Folder of <camera>.<mp4|avi|mkv|...> videos."),
        images: Path | None = typer.Option(None, "--images", help="Folder of <camera>/ image folders."),
        offsets: Path | None = typer.Option(None, "--offsets", help="JSON {camera: frames to skip} (sync)."),
        every: int = typer.Option(1, "--every", min=1, max=100_000, help="Keep every n-th frame."),
        trim: bool = typer.Option(False, "--trim", help="Cut all cameras to the shortest instead of refusing."),
        green_screen: bool = typer.Option(False, "--green-screen", help="Recorded on a green screen: key masks."),
        key_color: str = typer.Option("#00b140", "--key-color", help="Chroma-key colour, #rrggbb."),
        key_tolerance: float = typer.Option(30.0, "--key-tolerance", help="Hue tolerance, degrees (0..90]."),
        fps: float = typer.Option(30.0, "--fps", help="Source frame rate."),
        name: str | None = typer.Option(None, "--name", help="Capture name (default: the folder's)."),
        sequence: str = typer.Option("seq000", "--sequence", help="Sequence id."),
        subject: str = typer.Option("subject0", "--subject", help="Subject id."),
        side: str = typer.Option("right", "--side", help="Which hand: right or left."),
        working_width: int | None = typer.Option(None, "--working-width", min=16, max=100_000,
                                                 help="Width networks and thumbnails derive at (default 640)."),
        workers: int = typer.Option(0, "--workers", min=0, max=256, help="Processes (0: one per core)."),
        force: bool = typer.Option(False, "--force", help="Replace --out if it exists."),
    ) -> None:
        """Assemble a capture: frames matched to cameras by name, synchronised by index plus offsets."""
        from tqdm import tqdm

        from workers.capture.assemble import assemble_capture, find_sources, plan_frames, read_offsets
        from workers.capture.chroma import ChromaKey
        from workers.capture.schema import ID_PATTERN, CaptureError, HandModelInfo
        from workers.geometry.camera import CalibrationError, load_calibration

        if side not in ("right", "left"):
            raise typer.BadParameter(f"--side must be right or left, not {side!r}")
        for option, value in (("--sequence", sequence), ("--subject", subject)):
            if not ID_PATTERN.match(value):
                raise typer.BadParameter(f"{option} must match {ID_PATTERN.pattern}, not {value!r}")
        try:
            chroma = ChromaKey(color=key_color, tolerance_deg=key_tolerance) if green_screen else None
        except ValueError as exc:
            raise typer.BadParameter(str(exc)) from None
        try:
            cameras = load_calibration(calibration)
            offset_map = read_offsets(offsets, cameras)
            sources = find_sources(cameras, videos=videos, images=images)
            frames = plan_frames(sources, offset_map, every, trim)
            with tqdm(total=frames * len(cameras), unit="image", desc="assemble", file=sys.stderr) as bar:
                result = assemble_capture(cameras, out, videos=videos, images=images, offsets=offset_map,
                                          every=every, trim=trim, green_screen=green_screen, chroma=chroma, fps=fps,
                                          name=name, sequence_id=sequence, subject_id=subject,
                                          hand_model=HandModelInfo("handloop-builtin v1", is_mano=False, side=side),
                                          working_width_px=working_width, workers=workers, force=force,
                                          progress=bar.update)
        except (CaptureError, CalibrationError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        typer.echo(f"wrote {result.root}: {result.num_frames} frames x {result.num_cameras} cameras "
                   f"({result.image_format}{', chroma-key masks and previews/' if result.masks else ''}) in "
                   f"{result.seconds:.1f} s ({result.frames_per_s:.1f} frames/s)")
