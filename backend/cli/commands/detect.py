"""`handloop detect`: the pretrained detector's 21 keypoints on any photo (one view, no calibration), of the side
asked for where there are several hands, or every hand with --all."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

if TYPE_CHECKING:
    from workers.detector.types import ViewKeypoints


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


def hand_json(view: ViewKeypoints) -> dict[str, Any]:
    """One hand as printed: keypoints (21 x [x, y] px), scores (21), presence, `side` (the side it was read as) and
    `model_side` / `right_score` (which side the landmark model thinks it is; null where unknown)."""
    score = view.right_score
    return {"keypoints": view.keypoints_px.round(2).tolist(), "scores": view.scores.round(4).tolist(),
            "presence": round(view.presence, 4), "side": view.handedness, "model_side": view.model_side,
            "right_score": round(score, 4) if math.isfinite(score) else None}


def register(app: typer.Typer, bench: typer.Typer) -> None:
    @app.command("detect")
    def detect(
        images: list[Path] = typer.Argument(..., help="Image files (PNG, JPEG, ...)."),
        box: str | None = typer.Option(None, "--box", help="X,Y,W,H in pixels: where the hand is (every image)."),
        left: bool = typer.Option(False, "--left", help="Look for the left hand (of two, the one the model reads "
                                                        "as left; a single hand is given whatever its side)."),
        right: bool = typer.Option(False, "--right", help="Look for the right hand (the default)."),
        all_hands: bool = typer.Option(False, "--all", help="List every hand found, each with its side, under "
                                                            "\"hands\"."),
        json_out: bool = typer.Option(False, "--json", help="Print the JSON list as the last stdout line."),
    ) -> None:
        """Run the hand detector on each image; keypoints in FreiHAND order, pixels with (0, 0) at the centre of
        the top-left pixel. An image without a hand gets "keypoints": null and presence 0."""
        from workers.detector import DetectorInputError, DetectorUnavailableError
        from workers.detector.hands import hand_of_side
        from workers.detector.pipeline import check_box, detect_image_hands

        if left and right:
            typer.echo("error: --left and --right ask for different hands: give one of them", err=True)
            raise typer.Exit(code=2)
        side = "left" if left else "right"
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
                hands = detect_image_hands(image, parsed, handedness=side)
                view = hand_of_side(hands, side)
                record = {"image": str(path), **(hand_json(view) if view is not None else
                                                 {"keypoints": None, "scores": None, "presence": 0.0, "side": side,
                                                  "model_side": None, "right_score": None})}
                if all_hands:
                    record["hands"] = [hand_json(h) for h in hands]
                results.append(record)
        except (DetectorInputError, DetectorUnavailableError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        if not json_out:
            for r in results:
                found = "no hand found" if r["keypoints"] is None else (
                    f"{r['side']} hand, presence {r['presence']:.2f}, the model reads it as {r['model_side']}")
                extra = f" ({len(r['hands'])} hands in all)" if all_hands else ""
                typer.echo(f"{r['image']}: {found}{extra}")
        typer.echo(json.dumps(results))
