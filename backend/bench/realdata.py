"""The real recordings beside the checkout (`../shared/realdata`, never copied into the repository) and their
calibrations written in a format `handloop calibration convert` reads, as a lab would bring them.

handpose3d (TemugeB/handpose3d, MIT): two synchronised 720 x 720 webcams. Its calibration is the author's own
text layout: `c<i>.dat` holds K (3x3, pixels) and OpenCV's k1 k2 p1 p2 k3; `rot_trans_c<i>.dat` the board ->
camera pose (R, T; `rot_trans_c1.dat` adds, after a comment, camera 0 -> camera 1). Translations are in board
squares of unknown size (4.8 cm, docs/calibration.md).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from workers.geometry.camera import Camera

REALDATA_ENV = "HANDLOOP_REALDATA_DIR"
HANDPOSE3D = "handpose3d"
HANDPOSE3D_SIZE_PX = (720, 720)


class RealDataMissingError(FileNotFoundError):
    """The real recordings are not beside this checkout; the message says where they were looked for."""


def realdata_dir() -> Path:
    """`$HANDLOOP_REALDATA_DIR`, else `<checkout>/../shared/realdata`; RealDataMissingError when absent."""
    configured = os.environ.get(REALDATA_ENV)
    path = Path(configured) if configured else Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
    if not path.is_dir():
        raise RealDataMissingError(f"no real recordings at {path} (set {REALDATA_ENV} to the folder holding "
                                   f"{HANDPOSE3D}/)")
    return path


def handpose3d_dir() -> Path:
    """The handpose3d recording's folder, checked for the files used here."""
    root = realdata_dir() / HANDPOSE3D
    needed = ["c0.dat", "c1.dat", "rot_trans_c0.dat", "rot_trans_c1.dat", "cam0_test.mp4", "cam1_test.mp4"]
    missing = [name for name in needed if not (root / name).is_file()]
    if missing:
        raise RealDataMissingError(f"{root}: missing {', '.join(missing)}")
    return root


def _blocks(path: Path) -> dict[str, np.ndarray]:
    """The author's layout: a `name:` line, then rows of numbers; read up to the first '#' comment (after it
    `rot_trans_c1.dat` repeats the pose relative to camera 0, which the first one already gives)."""
    blocks: dict[str, list[float]] = {}
    key = None
    for line in path.read_text().splitlines():
        line = line.strip()
        if line.startswith("#"):
            break
        if line.endswith(":"):
            key = line[:-1]
            blocks[key] = []
        elif line and key is None:
            raise ValueError(f"{path}: numbers before the first 'name:' line")
        elif line:
            blocks[key] += [float(v) for v in line.split()]
    return {k: np.asarray(v) for k, v in blocks.items()}


def handpose3d_cameras() -> list[Camera]:
    """cam0, cam1 as handloop cameras in board squares: K and k1 k2 p1 p2 k3 from `c<i>.dat`, R and T board -> camera
    from `rot_trans_c<i>.dat`."""
    root = handpose3d_dir()
    width, height = HANDPOSE3D_SIZE_PX
    cameras = []
    for i in (0, 1):
        intrinsics, pose = _blocks(root / f"c{i}.dat"), _blocks(root / f"rot_trans_c{i}.dat")
        cameras.append(Camera(f"cam{i}", width, height, intrinsics["intrinsic"].reshape(3, 3),
                              intrinsics["distortion"][:5], pose["R"].reshape(3, 3), pose["T"].reshape(3)))
    return cameras


def write_handpose3d_opencv(out_dir: Path) -> Path:
    """The rig as OpenCV FileStorage files (`<camera>.yml`, `--from opencv`), translations in board squares."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for cam in handpose3d_cameras():
        fs = cv2.FileStorage(str(out_dir / f"{cam.name}.yml"), cv2.FILE_STORAGE_WRITE)
        fs.write("camera_matrix", cam.K)
        fs.write("distortion_coefficients", cam.dist.reshape(1, 5))
        fs.write("image_width", cam.width)
        fs.write("image_height", cam.height)
        fs.write("R", cam.R)
        fs.write("T", cam.t.reshape(3, 1))
        fs.release()
    return out_dir


def link_handpose3d_videos(out_dir: Path) -> Path:
    """A `--videos` folder for `capture assemble`: `<camera>.mp4` links to the recording's videos."""
    out_dir.mkdir(parents=True, exist_ok=True)
    root = handpose3d_dir()
    for i in (0, 1):
        link = out_dir / f"cam{i}.mp4"
        if not link.exists():
            link.symlink_to(root / f"cam{i}_test.mp4")
    return out_dir
