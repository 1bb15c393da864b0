"""hidden_by_mesh: a point behind a surface (by more than its tolerance) is hidden, one in front of it or
beside it is not; a point just under the surface (a joint under the skin) is not, within the tolerance."""

from __future__ import annotations

import numpy as np

from workers.geometry.camera import Camera
from workers.rendering.occlusion import hidden_by_mesh

# A 20 cm square at z = 1 m (world), facing a camera at the origin looking down +z.
SQUARE = np.array([[-0.1, -0.1, 1.0], [0.1, -0.1, 1.0], [0.1, 0.1, 1.0], [-0.1, 0.1, 1.0]])
FACES = np.array([[0, 1, 2], [0, 2, 3]])


def camera(name: str, R: np.ndarray, t: np.ndarray) -> Camera:
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    return Camera(name, 640, 480, K, np.zeros(5), R, t)


def test_points_behind_the_square_are_hidden_others_not():
    front = camera("front", np.eye(3), np.zeros(3))
    points = np.array([
        [0.0, 0.0, 1.5],    # straight behind the square
        [0.05, 0.02, 1.2],  # behind, off centre
        [0.0, 0.0, 0.8],    # in front of it
        [0.3, 0.0, 1.5],    # behind the plane but beside the square
        [0.0, 0.0, 1.004],  # 4 mm under the surface: within a 5 mm tolerance
    ])
    hidden = hidden_by_mesh(points, SQUARE, FACES, [front], np.full(5, 0.005))
    assert hidden.tolist() == [[True, True, False, False, False]]


def test_each_camera_sees_from_its_own_centre():
    front = camera("front", np.eye(3), np.zeros(3))
    # A camera behind the square at z = 2 m looking back down -z (rotation by pi about y): centre (0, 0, 2).
    R = np.diag([-1.0, 1.0, -1.0])
    back = camera("back", R, -R @ np.array([0.0, 0.0, 2.0]))
    points = np.array([[0.0, 0.0, 1.5], [0.0, 0.0, 0.5]])
    hidden = hidden_by_mesh(points, SQUARE, FACES, [front, back], np.zeros(2))
    assert hidden.tolist() == [[True, False], [False, True]]
