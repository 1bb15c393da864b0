"""The hand models an export needs: the right model, and the left one when left hands are exported (a left
hand's fit poses the left model). Shared by `handloop export` and the admin page's export job."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from workers.export.freihand import ExportError
from workers.export.records import SampleRecord
from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.loading import load_hand_model


def export_hand_models(mano_path: Path | None, records: Sequence[SampleRecord]
                       ) -> tuple[HandModelArrays, HandModelArrays | None]:
    """(right model, left model or None when no record is a left hand); ExportError when the left model is
    needed but cannot be loaded."""
    arrays = load_hand_model(mano_path)
    if not any(r.side == "left" for r in records):
        return arrays, None
    try:
        return arrays, load_hand_model(mano_path, "left")
    except (OSError, ValueError) as exc:
        raise ExportError(f"the export holds left hands but the left hand model cannot be loaded: {exc}") from exc
