"""The checks a submission and a draft share: clicks and masks against the sample's views."""

from __future__ import annotations

from typing import Any

from backend.schemas.tasks import ClickIn, MaskIn
from backend.services.captures.masks import decode_rle
from backend.services.errors import InvalidInputError


def in_image(x: float, y: float, width: int, height: int) -> bool:
    """Pixel centres are integers, so the image spans [-0.5, W - 0.5] x [-0.5, H - 0.5]."""
    return -0.5 <= x <= width - 0.5 and -0.5 <= y <= height - 0.5


def check_clicks(views: dict[int, tuple[int, int]], clicks: list[ClickIn], sample_id: int) -> None:
    """InvalidInputError naming the first click on a view not of the sample (`views`: id -> (width, height)
    px), given twice, or outside its image."""
    seen: set[tuple[int, int]] = set()
    for i, click in enumerate(clicks):
        size = views.get(click.view_id)
        if size is None:
            raise InvalidInputError(f"clicks[{i}]: view {click.view_id} is not a view of sample {sample_id}")
        if (click.view_id, click.keypoint) in seen:
            raise InvalidInputError(f"clicks[{i}]: keypoint {click.keypoint} of view {click.view_id} is given twice")
        seen.add((click.view_id, click.keypoint))
        if click.x is not None and click.y is not None and not in_image(click.x, click.y, *size):
            raise InvalidInputError(f"clicks[{i}]: ({click.x}, {click.y}) lies outside view {click.view_id}'s "
                                    f"{size[0]}x{size[1]} image")


def check_masks(views: dict[int, tuple[int, int]], masks: list[MaskIn], sample_id: int) -> list[tuple[int, Any]]:
    """The masks decoded, [(view id, (H, W) bool)]; InvalidInputError naming the first on a view not of the
    sample, of the wrong size, with run lengths that do not cover it, or a view given twice."""
    decoded = []
    for i, mask in enumerate(masks):
        size = views.get(mask.view_id)
        if size is None:
            raise InvalidInputError(f"masks[{i}]: view {mask.view_id} is not a view of sample {sample_id}")
        if (mask.width, mask.height) != size:
            raise InvalidInputError(f"masks[{i}]: mask is {mask.width}x{mask.height}; view {mask.view_id} is "
                                    f"{size[0]}x{size[1]}")
        try:
            decoded.append((mask.view_id, decode_rle(mask.rle, mask.width, mask.height)))
        except InvalidInputError as exc:
            raise InvalidInputError(f"masks[{i}]: {exc.message}") from exc
    if len({view_id for view_id, _ in decoded}) != len(decoded):
        raise InvalidInputError("masks: one view is given twice")
    return decoded
