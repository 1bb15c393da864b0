"""Calibrated pinhole cameras with OpenCV distortion, and their JSON file format.

Conventions (docs/conventions.md): extrinsics map world to camera, X_c = R X_w + t, in metres;
pixel (0, 0) is the centre of the top-left pixel; distortion is OpenCV's (k1, k2, p1, p2, k3).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

CAMERA_KEYS = frozenset({"name", "width", "height", "K", "dist", "R", "t"})


class CalibrationError(ValueError):
    """A calibration file or value is malformed; the message names the file and field at fault."""


def _as_array(value: Any, shape: tuple[int, ...], field_name: str, where: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: field '{field_name}' is not numeric") from exc
    if array.shape != shape:
        raise CalibrationError(f"{where}: field '{field_name}' must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise CalibrationError(f"{where}: field '{field_name}' contains non-finite numbers")
    return array


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera.

    Attributes:
        name: unique camera name within a rig, e.g. "cam0".
        width, height: image size in pixels.
        K: (3, 3) intrinsics in pixels.
        dist: (5,) OpenCV distortion k1, k2, p1, p2, k3.
        R: (3, 3) rotation world -> camera.
        t: (3,) translation world -> camera, metres.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        where = f"camera '{self.name}'"
        if not isinstance(self.name, str) or not self.name:
            raise CalibrationError("camera: field 'name' must be a non-empty string")
        for key in ("width", "height"):
            value = getattr(self, key)
            is_int = isinstance(value, int | np.integer) and not isinstance(value, bool)
            if not is_int or not 1 <= value <= 100_000:
                raise CalibrationError(f"{where}: field '{key}' must be an integer in 1..100000, not {value!r}")
        object.__setattr__(self, "K", _as_array(self.K, (3, 3), "K", where))
        object.__setattr__(self, "dist", _as_array(self.dist, (5,), "dist", where))
        object.__setattr__(self, "R", _as_array(self.R, (3, 3), "R", where))
        object.__setattr__(self, "t", _as_array(self.t, (3,), "t", where))
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0 or not np.allclose(self.K[2], (0, 0, 1)):
            raise CalibrationError(f"{where}: field 'K' needs positive focal lengths and last row (0, 0, 1)")
        if not np.allclose(self.R @ self.R.T, np.eye(3), atol=1e-6) or np.linalg.det(self.R) <= 0:
            raise CalibrationError(f"{where}: field 'R' is not a rotation matrix")

    @property
    def center_world(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, metres."""
        return -self.R.T @ self.t

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix K [R | t] (ignores distortion)."""
        return self.K @ np.concatenate([self.R, self.t[:, None]], axis=1)

    def scaled(self, width: int, *, square_pixels: bool = False) -> Camera:
        """The same camera at another image width (height round(height * width / self.width), the aspect
        ratio kept as nearly as whole pixels allow).

        Each axis is scaled by its own factor, the one an image resized to that size has: sx = width /
        self.width, sy = height / self.height. Pixel-centre convention: u' = sx (u + 0.5) - 0.5,
        v' = sy (v + 0.5) - 0.5, so the principal point shifts by (s - 1) / 2. `square_pixels`: one factor,
        sx, for both axes: a sensor read out (or a renderer drawing) at the new size with the same field of
        view, nothing resized; fx = fy stays so.
        """
        sx = width / self.width
        height = max(1, round(self.height * sx))
        sy = sx if square_pixels else height / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[0, 1] *= sx
        K[1, 1] *= sy
        K[0, 2] = sx * (K[0, 2] + 0.5) - 0.5
        K[1, 2] = sy * (K[1, 2] + 0.5) - 0.5
        return replace(self, width=int(width), height=height, K=K)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "width": int(self.width),
            "height": int(self.height),
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "camera") -> Camera:
        """Build a camera from its JSON object; unknown or missing keys raise CalibrationError."""
        if not isinstance(data, dict):
            raise CalibrationError(f"{where}: expected a JSON object, got {type(data).__name__}")
        unknown = set(data) - CAMERA_KEYS
        if unknown:
            raise CalibrationError(f"{where}: unknown field(s) {sorted(unknown)}")
        missing = CAMERA_KEYS - set(data)
        if missing:
            raise CalibrationError(f"{where}: missing field(s) {sorted(missing)}")
        try:
            return cls(**data)
        except CalibrationError as exc:
            raise CalibrationError(f"{where}: {exc}") from None


def save_calibration(cameras: list[Camera], path: Path) -> None:
    """Write a rig as JSON: {"cameras": [camera, ...]} (one object per camera, see Camera.to_dict)."""
    path.write_text(json.dumps({"cameras": [c.to_dict() for c in cameras]}, indent=1))


def load_calibration(path: Path) -> list[Camera]:
    """Read and validate a calibration file written by `save_calibration`."""
    where = str(path)
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise CalibrationError(f"{where}: file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{where}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or set(data) != {"cameras"} or not isinstance(data["cameras"], list):
        raise CalibrationError(f"{where}: expected an object with the single key 'cameras' (a list)")
    cameras = [Camera.from_dict(c, where=f"{where}: cameras[{i}]") for i, c in enumerate(data["cameras"])]
    if not cameras:
        raise CalibrationError(f"{where}: 'cameras' is empty")
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise CalibrationError(f"{where}: camera names are not unique: {names}")
    return cameras


def look_at(center_world: np.ndarray, target_world: np.ndarray, up_world: np.ndarray) -> np.ndarray:
    """(3, 3) rotation world -> camera for a camera at `center_world` looking at `target_world`.

    Camera axes follow OpenCV: x right, y down, z forward.
    """
    z = np.asarray(target_world, float) - np.asarray(center_world, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, -np.asarray(up_world, float))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("up vector is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def horizontal_fov_rad(camera: Camera) -> float:
    return 2.0 * math.atan(camera.width / (2.0 * camera.K[0, 0]))
