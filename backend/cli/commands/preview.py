"""`handloop preview`: all views of one frame in a grid, with ground-truth keypoints and skeleton."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("preview")
    def preview(
        capture: Path = typer.Argument(..., help="Capture folder."),
        frame: int = typer.Option(0, "--frame", min=0, help="Frame index within the sequence."),
        sequence: str | None = typer.Option(None, "--sequence", help="Sequence id (default: the first)."),
        out: Path = typer.Option(..., "--out", help="Output image (.png or .jpg)."),
        masks: bool = typer.Option(False, "--masks", help="Outline the chroma-key (cyan) and hand (magenta) masks."),
        tile_width: int = typer.Option(480, min=64, max=2048, help="Width of each view in the grid, pixels."),
        zoom: bool = typer.Option(True, "--zoom/--full",
                                  help="Crop each view around the hand (with ground truth), or show whole views."),
    ) -> None:
        """Draw every view of one frame in a grid; keypoints are coloured per finger (hollow: not visible)."""
        import cv2

        from workers.capture import CaptureError, read_capture
        from workers.capture.preview import find_frame, preview_frame

        if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
            raise typer.BadParameter(f"--out must end in .png or .jpg, not {out.name!r}")
        try:
            cap = read_capture(capture)
            ref = find_frame(cap, frame, sequence)
            grid = preview_frame(cap, ref, tile_width=tile_width, outline_masks=masks, zoom=zoom)
        except CaptureError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        out.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR)):
            typer.echo(f"error: {out}: could not write the image", err=True)
            raise typer.Exit(code=2)
        typer.echo(f"wrote {out} ({ref.sequence_id} frame {ref.index}, {len(cap.cameras)} views)")
