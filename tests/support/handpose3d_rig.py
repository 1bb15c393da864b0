"""The real two-webcam recording TemugeB/handpose3d (/work/shared/realdata/README.md) for tests: its folder, or a
skip that says where it was looked for (backend/bench/realdata.py reads it, for the tests and `bench realrig`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from backend.bench import realdata
from workers.geometry.camera import Camera


def handpose3d_dir() -> Path:
    """The recording's folder; skips the calling test when it is absent."""
    try:
        return realdata.handpose3d_dir()
    except realdata.RealDataMissingError as exc:
        pytest.skip(f"the real recording is absent: {exc}")


def handpose3d_cameras(folder: Path | None = None) -> list[Camera]:
    """cam0, cam1 in board squares (board -> camera), as the recording's .dat files give them."""
    handpose3d_dir()
    return realdata.handpose3d_cameras()
