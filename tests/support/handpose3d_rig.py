"""The real two-webcam recording TemugeB/handpose3d (/work/shared/realdata/README.md): where it is, and its
calibration (the author's own .dat text layout) as handloop cameras in board-square units."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from workers.geometry.camera import Camera

REPO = Path(__file__).resolve().parents[2]
SIZE = 720  # both videos are 720 x 720 px


def realdata_dir() -> Path:
    """HANDLOOP_REALDATA_DIR, else ../shared/realdata beside the checkout."""
    return Path(os.environ.get("HANDLOOP_REALDATA_DIR") or REPO.parent / "shared" / "realdata")


def handpose3d_dir() -> Path:
    """The recording's folder; skips the calling test when it is absent."""
    folder = realdata_dir() / "handpose3d"
    if not (folder / "c0.dat").is_file():
        pytest.skip(f"the real recording is absent ({folder}; set HANDLOOP_REALDATA_DIR)")
    return folder


def _blocks(path: Path) -> dict[str, np.ndarray]:
    """'label:' lines followed by rows of numbers, up to the first '#' comment (the file's later, relative pose)."""
    blocks: dict[str, list[list[float]]] = {}
    label = None
    for line in path.read_text().splitlines():
        line = line.strip()
        if line.startswith("#"):
            break
        if line.endswith(":"):
            label = line[:-1]
            blocks[label] = []
        elif line and label is not None:
            blocks[label].append([float(v) for v in line.split()])
    return {k: np.array(v, dtype=np.float64) for k, v in blocks.items()}


def handpose3d_cameras(folder: Path) -> list[Camera]:
    """cam0, cam1: K and k1 k2 p1 p2 k3 from cN.dat, R and T (board -> camera, board squares) from rot_trans_cN.dat."""
    cameras = []
    for i in range(2):
        intr = _blocks(folder / f"c{i}.dat")
        extr = _blocks(folder / f"rot_trans_c{i}.dat")
        cameras.append(Camera(f"cam{i}", SIZE, SIZE, intr["intrinsic"], intr["distortion"].ravel(), extr["R"],
                              extr["T"].ravel()))
    return cameras
