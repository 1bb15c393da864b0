"""COLMAP's text model: `cameras.txt` + `images.txt` (PATH: the folder holding both, e.g. sparse/0).

cameras.txt: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...`. Models read: SIMPLE_PINHOLE (f cx cy), PINHOLE
(fx fy cx cy), SIMPLE_RADIAL (f cx cy k), RADIAL (f cx cy k1 k2), OPENCV (fx fy cx cy k1 k2 p1 p2),
FULL_OPENCV (... k3 k4 k5 k6: rational, accepted only with k4..k6 = 0); fisheye and the other models are
refused by name. COLMAP puts the top-left pixel's centre at (0.5, 0.5), OpenCV at (0, 0): cx, cy are
shifted by -0.5.
images.txt: two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME` then its 2D points. The
quaternion (w, x, y, z; scalar first) and T map world -> camera (X_c = R(q) X_w + T). One image per
camera of the rig: its name's first folder (`cam0/000000.jpg`) or else its stem names the camera.
A reconstruction's scale is arbitrary unless it was aligned to metric units (model_aligner).
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

import numpy as np

from workers.rigs.formats.common import FormatError, RawCamera

DEFAULT_UNIT = "m"
# model -> (parameter names), in COLMAP's order
MODELS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
}
UNSUPPORTED = ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "THIN_PRISM_FISHEYE", "FOV")
QUATERNION_TOL = 1e-6


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of a unit quaternion (w, x, y, z), Hamilton convention as COLMAP's."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _data_lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise FormatError(f"{path}: file not found") from None
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a text file") from None
    return [(n, line) for n, line in enumerate(text.splitlines(), 1) if not line.startswith("#")]


def _numbers(fields: list[str], where: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in fields])
    except ValueError:
        raise FormatError(f"{where}: expected numbers, got {' '.join(fields)!r}") from None
    if not np.all(np.isfinite(values)):
        raise FormatError(f"{where}: non-finite number")
    return values


def _intrinsics(model: str, params: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray, bool]:
    """(K in OpenCV pixel centres, OpenCV coefficients, supported) from one cameras.txt line."""
    if model in UNSUPPORTED or model not in MODELS:
        return np.eye(3), np.zeros(5), False
    names = MODELS[model]
    if len(params) != len(names):
        raise FormatError(f"{where}: model {model} takes {len(names)} parameters {names}, got {len(params)}")
    p = dict(zip(names, params, strict=True))
    fx, fy = (p["f"], p["f"]) if "f" in p else (p["fx"], p["fy"])
    K = np.array([[fx, 0.0, p["cx"] - 0.5], [0.0, fy, p["cy"] - 0.5], [0.0, 0.0, 1.0]])
    dist = np.array([p.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")])
    return K, dist, True


def read(path: Path) -> tuple[list[RawCamera], list[str]]:
    """One camera per image of images.txt, in image-id order, with its cameras.txt intrinsics."""
    folder = Path(path)
    if folder.is_file():
        folder = folder.parent
    intrinsics: dict[int, tuple[str, int, int, np.ndarray, np.ndarray, bool]] = {}
    cam_file = folder / "cameras.txt"
    for n, line in _data_lines(cam_file):
        if not line.strip():
            continue
        fields = line.split()
        where = f"{cam_file}: line {n}"
        if len(fields) < 4:
            raise FormatError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...")
        try:
            cam_id, width, height = int(fields[0]), int(fields[2]), int(fields[3])
        except ValueError:
            raise FormatError(f"{where}: CAMERA_ID, WIDTH and HEIGHT must be integers") from None
        K, dist, ok = _intrinsics(fields[1], _numbers(fields[4:], where), where)
        intrinsics[cam_id] = (fields[1], width, height, K, dist, ok)
    img_file = folder / "images.txt"
    lines = _data_lines(img_file)
    raws: list[tuple[int, RawCamera]] = []
    for (n, line) in lines[0::2]:  # every other data line is an image; the next holds its 2D points
        fields = line.split()
        where = f"{img_file}: line {n}"
        if len(fields) < 10:
            raise FormatError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
        values = _numbers(fields[1:8], where)
        q, T = values[:4], values[4:]
        try:
            image_id, cam_id = int(fields[0]), int(fields[8])
        except ValueError:
            raise FormatError(f"{where}: IMAGE_ID and CAMERA_ID must be integers") from None
        name_path = PurePosixPath(" ".join(fields[9:]))
        name = name_path.parts[0] if len(name_path.parts) > 1 else name_path.stem
        where = f"{img_file}: camera {name!r} (line {n})"
        if abs(np.linalg.norm(q) - 1.0) > QUATERNION_TOL:
            raise FormatError(f"{where}: field 'QW QX QY QZ' is not a unit quaternion (norm {np.linalg.norm(q):.6g})")
        if cam_id not in intrinsics:
            raise FormatError(f"{where}: CAMERA_ID {cam_id} is not in {cam_file.name}")
        model, width, height, K, dist, ok = intrinsics[cam_id]
        raws.append((image_id, RawCamera(name=name, K=K, dist=dist, R=quaternion_to_matrix(q), t=T, width=width,
                                         height=height, model=model, supported=ok)))
    used = {r.name for _, r in raws}
    notes = [f"{img_file}: COLMAP's scale is arbitrary unless the model was aligned to metric units: check the "
             "rig span"]
    if len(used) < len(raws):
        names = [r.name for _, r in raws]
        repeated = sorted({x for x in names if names.count(x) > 1})
        raise FormatError(f"{img_file}: camera(s) {repeated} have several images; give one image per camera "
                          "(one frame of the rig)")
    return [r for _, r in sorted(raws, key=lambda item: item[0])], notes
