"""Choose the hand model: the user's MANO files when given, else the built-in procedural stand-in."""

from __future__ import annotations

import logging
from functools import lru_cache
from pathlib import Path

from workers.handmodel.arrays import HandModelArrays

log = logging.getLogger(__name__)

STAND_IN_NOTICE = (
    "Using handloop's built-in procedural hand, a stand-in for MANO with the same interface. "
    "Set HANDLOOP_MANO_PATH to your licensed MANO_RIGHT.pkl (or its folder) to use the real model."
)


@lru_cache(maxsize=8)
def load_hand_model(mano_path: Path | None = None, side: str = "right") -> HandModelArrays:
    """The hand model's arrays.

    Args:
        mano_path: a MANO pickle or a folder with MANO_RIGHT.pkl / MANO_LEFT.pkl; None = built-in.
        side: "right" or "left".
    """
    if side not in ("right", "left"):
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    if mano_path is not None:
        from workers.handmodel.mano_loader import load_mano  # deferred: only the chosen model's loader

        return load_mano(Path(mano_path), side=side)
    from workers.handmodel.builtin import build_builtin_hand  # deferred: as load_mano (scipy)

    log.info(STAND_IN_NOTICE)
    return build_builtin_hand(side=side)

