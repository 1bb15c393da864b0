"""`handloop detect`: the pretrained detector's 21 keypoints on any photo (one view, no calibration)."""

from __future__ import annotations

import json
from pathlib import Path

import typer


def parse_box(text: str) -> tuple[float, float, float, float]:
    """'X,Y,W,H' -> four floats (checked against each image later)."""
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise typer.BadParameter(f"--box must be X,Y,W,H (4 numbers), got {text!r}") from None
    if len(values) != 4:
        raise typer.BadParameter(f"--box must be X,Y,W,H (4 numbers), got {text!r}")
    return values  # type: ignore[return-value]


def read_rgb(path: Path):  # -> (H, W, 3) uint8; DetectorInputError naming the file
    """Decode a whole image with Pillow (a truncated file raises instead of decoding grey)."""
    import numpy as np
    from PIL import Image, UnidentifiedImageError

    from workers.detector import DetectorInputError

    try:
        with Image.open(path) as im:
            im.load()
            return np.asarray(im.convert("RGB"))
    except FileNotFoundError:
        raise DetectorInputError(f"{path}: file not found") from None
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
        raise DetectorInputError(f"{path}: not a readable image ({exc})") from None


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("detect")
    def detect(
        images: list[Path] = typer.Argument(..., help="Image files (PNG, JPEG, ...)."),
        box: str | None = typer.Option(None, "--box", help="X,Y,W,H in pixels: where the hand is (every image)."),
        left: bool = typer.Option(False, "--left", help="The hand is a left hand."),
        json_out: bool = typer.Option(False, "--json", help="Print the JSON list as the last stdout line."),
    ) -> None:
        """Run the hand detector on each image; keypoints in FreiHAND order, pixels with (0, 0) at the centre of
        the top-left pixel. An image without a hand gets "keypoints": null and presence 0."""
        from workers.detector import DetectorInputError, DetectorUnavailableError
        from workers.detector.pipeline import check_box, detect_image

        parsed = parse_box(box) if box is not None else None
        try:
            # Every image is read and checked before any detection: a bad one fails the run, nothing partial.
            decoded = [read_rgb(path) for path in images]
            if parsed is not None:
                for path, image in zip(images, decoded, strict=True):
                    try:
                        check_box(parsed, image.shape[1], image.shape[0])
                    except DetectorInputError as exc:
                        raise DetectorInputError(f"{path}: {exc}") from None
            results = []
            for path, image in zip(images, decoded, strict=True):
                view = detect_image(image, parsed, handedness="left" if left else "right")
                results.append({"image": str(path),
                                "keypoints": None if view is None else view.keypoints_px.round(2).tolist(),
                                "scores": None if view is None else view.scores.round(4).tolist(),
                                "presence": 0.0 if view is None else round(view.presence, 4)})
        except (DetectorInputError, DetectorUnavailableError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        if not json_out:
            for r in results:
                typer.echo(f"{r['image']}: " + ("no hand found" if r["keypoints"] is None else
                                                f"hand, presence {r['presence']:.2f}"))
        typer.echo(json.dumps(results))
