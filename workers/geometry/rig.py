"""The default capture rig: FreiHAND's eight cameras at the corners of a 1 m cube.

Paper (supplementary, "FreiHAND details"): two Basler acA800-510uc (800x600) and six acA1300-200uc
(1280x1024) colour cameras, 4.8 um pixels, fixed 4 mm or 6 mm lenses, at the corners of a cube of edge
1 m; the subject reaches in through one face so the hand sits near the centre.

World frame: origin at the cube centre, z up, metres. The forearm enters through the -y face.
Which camera has which lens is not published; our assignment is documented in `RIG_LAYOUT`.
"""

from __future__ import annotations

import itertools

import numpy as np

from workers.geometry.camera import Camera, look_at

PIXEL_PITCH_MM = 0.0048
CUBE_EDGE_M = 1.0
DEFAULT_WIDTH_PX = 320

# (sensor width, sensor height, focal length mm, k1, k2) per corner, corners in itertools.product order
# of (x, y, z) signs. Radial distortion: typical magnitudes for 4 mm and 6 mm C-mount lenses.
_SENSOR_800 = (800, 600)
_SENSOR_1280 = (1280, 1024)
RIG_LAYOUT: tuple[tuple[tuple[int, int], float, float, float], ...] = (
    (_SENSOR_1280, 6.0, -0.08, 0.05),
    (_SENSOR_1280, 6.0, -0.08, 0.05),
    (_SENSOR_800, 4.0, -0.15, 0.08),
    (_SENSOR_1280, 4.0, -0.15, 0.08),
    (_SENSOR_1280, 6.0, -0.08, 0.05),
    (_SENSOR_1280, 6.0, -0.08, 0.05),
    (_SENSOR_800, 4.0, -0.15, 0.08),
    (_SENSOR_1280, 4.0, -0.15, 0.08),
)


def default_rig(width_px: int | None = DEFAULT_WIDTH_PX, seed: int = 0,
                aim_jitter_m: float = 0.02) -> list[Camera]:
    """Eight calibrated cameras at the cube's corners aimed near its centre.

    Args:
        width_px: working image width; every camera is scaled to it (None keeps sensor resolution).
        seed: seeds the small aiming and roll jitter a real rig has.
        aim_jitter_m: standard deviation of each camera's aim point around the centre, metres.
    Returns:
        Cameras "cam0".."cam7" at full or working resolution.
    """
    rng = np.random.default_rng(seed)
    half = CUBE_EDGE_M / 2
    cameras = []
    for i, (signs, (sensor, focal_mm, k1, k2)) in enumerate(
        zip(itertools.product((-1, 1), repeat=3), RIG_LAYOUT, strict=True)
    ):
        center = half * np.asarray(signs, dtype=float)
        target = rng.normal(0.0, aim_jitter_m, 3)
        roll = rng.normal(0.0, np.deg2rad(2.0))
        R = look_at(center, target, up_world=np.array([0.0, 0.0, 1.0]))
        c, s = np.cos(roll), np.sin(roll)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ R
        width, height = sensor
        f_px = focal_mm / PIXEL_PITCH_MM
        principal = np.array([(width - 1) / 2, (height - 1) / 2]) + rng.normal(0, 4.0, 2)
        K = np.array([[f_px, 0, principal[0]], [0, f_px, principal[1]], [0, 0, 1.0]])
        dist = np.array([k1, k2, 0.0, 0.0, 0.0])
        cam = Camera(f"cam{i}", width, height, K, dist, R, -R @ center)
        cameras.append(cam.scaled(width_px, square_pixels=True) if width_px else cam)  # rendered at that size
    return cameras
