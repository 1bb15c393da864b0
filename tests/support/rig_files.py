"""Writers of other toolchains' calibration files, for tests: each writes a known rig the way that
toolchain would (its units, rotation representation, transposes, pixel origin), independently of the
readers in workers/rigs/formats."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.rig import default_rig


def distorted_rig() -> list[Camera]:
    """The default rig at sensor resolution with all five OpenCV coefficients non-zero and some skew-free
    non-square pixels."""
    rig = default_rig(None, seed=3)
    out = []
    for i, cam in enumerate(rig):
        K = cam.K.copy()
        K[1, 1] *= 1.0 + 0.001 * i
        dist = np.array([-0.11 + 0.01 * i, 0.07, 0.0012 * (i - 3), -0.0007 * i, 0.013 - 0.002 * i])
        out.append(replace(cam, K=K, dist=dist))
    return out


def _rvec(R: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(R)[0].ravel()


def _toml_list(values) -> str:
    return "[" + ", ".join(_toml_list(v) if isinstance(v, list | np.ndarray) else repr(float(v)) for v in values) + "]"


def write_anipose(cameras: list[Camera], path: Path, scale: float = 1.0, fisheye: str | None = None) -> Path:
    """aniposelib CameraGroup.dump layout; lengths multiplied by `scale` (1000: millimetres)."""
    lines = []
    for i, cam in enumerate(cameras):
        lines += [f"[cam_{i}]", f'name = "{cam.name}"', f"size = [{cam.width}, {cam.height}]",
                  f"matrix = {_toml_list(cam.K.tolist())}",
                  f"distortions = {_toml_list(cam.dist[:4] if cam.name == fisheye else cam.dist)}",
                  f"rotation = {_toml_list(_rvec(cam.R))}", f"translation = {_toml_list(cam.t * scale)}"]
        if cam.name == fisheye:
            lines.append("fisheye = true")
        lines.append("")
    lines += ["[metadata]", "adjusted = false", "error = 0.3", ""]
    path.write_text("\n".join(lines))
    return path


def _easymocap_file(path: Path, entries: list[tuple[str, object]]) -> None:
    """EasyMocap's own FileStorage writer (easymocap/mytools/camera_utils.py): YAML text, matrices with ten
    decimals, lists of quoted strings, reals."""
    lines = ["%YAML:1.0", "---"]
    for key, value in entries:
        if isinstance(value, list):
            lines.append(f"{key}:")
            lines += [f'  - "{v}"' for v in value]
        elif isinstance(value, np.ndarray):
            lines += [f"{key}: !!opencv-matrix", f"  rows: {value.shape[0]}", f"  cols: {value.shape[1]}", "  dt: d",
                      "  data: [{}]".format(", ".join(f"{v:.10f}" for v in value.reshape(-1)))]
        else:
            lines.append(f"{key}: {float(value):.10f}")
    path.write_text("\r\n".join(lines) + "\r\n")


def write_easymocap(cameras: list[Camera], folder: Path, drop_extri: str | None = None) -> Path:
    """EasyMocap's write_intri / write_extri; `drop_extri` leaves one camera out of extri.yml."""
    folder.mkdir(parents=True, exist_ok=True)
    intri: list[tuple[str, object]] = [("names", [c.name for c in cameras])]
    for cam in cameras:
        intri += [(f"K_{cam.name}", cam.K), (f"dist_{cam.name}", cam.dist.reshape(1, 5)),
                  (f"H_{cam.name}", cam.height), (f"W_{cam.name}", cam.width)]
    kept = [c for c in cameras if c.name != drop_extri]
    extri: list[tuple[str, object]] = [("names", [c.name for c in kept])]
    for cam in kept:
        extri += [(f"R_{cam.name}", _rvec(cam.R).reshape(3, 1)), (f"Rot_{cam.name}", cam.R),
                  (f"T_{cam.name}", cam.t.reshape(3, 1))]
    _easymocap_file(folder / "intri.yml", intri)
    _easymocap_file(folder / "extri.yml", extri)
    return folder


def write_opencv(cameras: list[Camera], folder: Path, rational: str | None = None) -> Path:
    """One calibration-sample style FileStorage per camera; `rational` gives that camera 8 coefficients."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, cam in enumerate(cameras):
        fs = cv2.FileStorage(str(folder / f"{cam.name}.{'xml' if i % 2 else 'yml'}"), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", cam.width)
        fs.write("image_height", cam.height)
        fs.write("camera_matrix", cam.K)
        dist = np.concatenate([cam.dist, [0.01, 0.0, 0.0]]) if cam.name == rational else cam.dist
        fs.write("distortion_coefficients", dist.reshape(-1, 1))
        fs.write("R", _rvec(cam.R).reshape(3, 1) if i % 2 else cam.R)
        fs.write("T", cam.t.reshape(3, 1))
        fs.release()
    return folder


def write_panoptic(cameras: list[Camera], path: Path) -> Path:
    """CMU Panoptic calibration JSON, centimetres, t as a 3x1 nested list."""
    rows = [{"name": cam.name, "type": "hd", "resolution": [cam.width, cam.height], "panel": 0, "node": i,
             "K": cam.K.tolist(), "distCoef": cam.dist.tolist(), "R": cam.R.tolist(),
             "t": (cam.t * 100.0).reshape(3, 1).tolist()} for i, cam in enumerate(cameras)]
    rows.append({"name": "50_01", "type": "kinect-color", "resolution": [1920, 1080], "K": np.eye(3).tolist(),
                 "distCoef": [0.0] * 5, "R": np.eye(3).tolist(), "t": [[0.0], [0.0], [0.0]]})
    path.write_text(json.dumps({"calibDataSource": "test", "cameras": rows}))
    return path


def write_multical(cameras: list[Camera], path: Path, chain: bool = False, model: str = "standard") -> Path:
    """multical's calibration.json: poses relative to cameras[0] (`chain`: each relative to the previous one)."""
    def relative(cam: Camera, ref: Camera) -> dict:
        R = cam.R @ ref.R.T
        return {"R": R.tolist(), "T": (cam.t - R @ ref.t).tolist()}

    base = cameras[0]
    poses: dict = {base.name: relative(base, base)}
    for i, cam in enumerate(cameras[1:], 1):
        ref = cameras[i - 1] if chain else base
        poses[f"{cam.name}_to_{ref.name}"] = relative(cam, ref)
    data = {"cameras": {cam.name: {"model": model, "image_size": [cam.width, cam.height], "K": cam.K.tolist(),
                                   "dist": [cam.dist.tolist()]} for cam in cameras},
            "camera_poses": poses}
    path.write_text(json.dumps(data))
    return path


def write_jarvis(cameras: list[Camera], folder: Path) -> Path:
    """JARVIS per-camera YAML: MATLAB's transposed intrinsicMatrix and R, T in millimetres."""
    folder.mkdir(parents=True, exist_ok=True)
    for cam in cameras:
        fs = cv2.FileStorage(str(folder / f"{cam.name}.yaml"), cv2.FILE_STORAGE_WRITE)
        fs.write("intrinsicMatrix", np.ascontiguousarray(cam.K.T))
        fs.write("distortionCoefficients", cam.dist.reshape(1, 5))
        fs.write("R", np.ascontiguousarray(cam.R.T))
        fs.write("T", (cam.t * 1000.0).reshape(1, 3))
        fs.release()
    return folder


def _quaternion(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of a rotation matrix (Shepperd's method)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def write_colmap(cameras: list[Camera], folder: Path, model: str = "OPENCV") -> Path:
    """COLMAP text model; pixel centres at +0.5; k3 must be 0 for OPENCV."""
    folder.mkdir(parents=True, exist_ok=True)
    cam_lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    img_lines = ["# Image list with two lines of data per image:"]
    for i, cam in enumerate(cameras, 1):
        fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2] + 0.5, cam.K[1, 2] + 0.5
        k1, k2, p1, p2, k3 = cam.dist
        params = {"OPENCV": (fx, fy, cx, cy, k1, k2, p1, p2),
                  "FULL_OPENCV": (fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0),
                  "OPENCV_FISHEYE": (fx, fy, cx, cy, k1, k2, 0.0, 0.0)}[model]
        cam_lines.append(f"{i} {model} {cam.width} {cam.height} " + " ".join(repr(float(v)) for v in params))
        q = _quaternion(cam.R)
        img_lines.append(f"{10 + i} " + " ".join(repr(float(v)) for v in (*q, *cam.t)) + f" {i} {cam.name}/000000.jpg")
        img_lines.append("100.5 200.25 -1")
    (folder / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
    (folder / "images.txt").write_text("\n".join(img_lines) + "\n")
    return folder


def write_caliscope(cameras: list[Camera], path: Path, layout: str = "camera_array", matrix_rotation: bool = False,
                    ignore: str | None = None, unposed: str | None = None) -> Path:
    """caliscope's CameraArray.to_toml ([cameras.N], Rodrigues rotation) or, `layout` "config", its older config.toml
    ([cam_N] beside [charuco] and settings); `matrix_rotation` writes 3x3 rotations (older files); `ignore` marks
    that camera ignore = true; `unposed` leaves that camera's rotation and translation out. cam_id = list index."""
    lines = ["CreationDate = 2023-05-06T11:12:27.631355", "camera_count = 0", ""] if layout == "config" else []
    for i, cam in enumerate(cameras):
        lines += [f"[cameras.{i}]" if layout == "camera_array" else f"[cam_{i}]", f"cam_id = {i}", "rotation_count = 0",
                  "error = 0.19", f"ignore = {'true' if cam.name == ignore else 'false'}",
                  f"size = [{cam.width}, {cam.height}]", f"matrix = {_toml_list(cam.K.tolist())}",
                  f"distortions = {_toml_list(cam.dist)}"]
        if cam.name != unposed:
            rotation = cam.R.tolist() if matrix_rotation else _rvec(cam.R)
            lines += [f"translation = {_toml_list(cam.t)}", f"rotation = {_toml_list(rotation)}"]
        lines += ["exposure = -7", "grid_count = 24", "fisheye = false", ""]
    if layout == "config":
        lines += ["[capture_volume]", "stage = 2", "", "[charuco]", "columns = 4", "rows = 5", 'units = "inch"',
                  "square_size_override_cm = 5.4", ""]
    path.write_text("\n".join(lines))
    return path


def write_pose2sim(cameras: list[Camera], path: Path) -> Path:
    """Pose2Sim/calibration.py toml_write: [<name>] tables, float sizes, four coefficients k1 k2 p1 p2, metres."""
    lines = []
    for cam in cameras:
        r, t, d, K = ([repr(float(v)) for v in a.ravel()] for a in (_rvec(cam.R), cam.t, cam.dist, cam.K))
        lines += [f"[{cam.name}]", f'name = "{cam.name}"', f"size = [ {float(cam.width)}, {float(cam.height)}]",
                  f"matrix = [ [ {K[0]}, 0.0, {K[2]}], [ 0.0, {K[4]}, {K[5]}], [ 0.0, 0.0, 1.0]]",
                  f"distortions = [ {d[0]}, {d[1]}, {d[2]}, {d[3]}]",
                  f"rotation = [ {r[0]}, {r[1]}, {r[2]}]", f"translation = [ {t[0]}, {t[1]}, {t[2]}]",
                  "fisheye = false", ""]
    lines += ["[metadata]", "adjusted = false", "error = 0.0", ""]
    path.write_text("\n".join(lines))
    return path
