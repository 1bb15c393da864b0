"""The 3D view starts at the hand, with the rig's own up, from the cameras' side (issue 38 item 13): a real rig's
world is often its first camera's (y down, z forward), where the old fixed "+z up, eye beside the hand" showed the
real recording's hand from a wrong side or not at all."""

from __future__ import annotations

import numpy as np

from backend.viewer.scene import EYE_DISTANCE_M, SampleScene, SceneCamera, record_scene, viewpoint
from tests.support.handpose3d_rig import handpose3d_cameras


def _look_at_camera(centre: np.ndarray, target: np.ndarray, world_up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R (world -> camera, OpenCV: x right, y down, z forward) and t of an upright camera at `centre`."""
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(z, world_up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def _hand(at: np.ndarray) -> np.ndarray:
    return at + np.random.default_rng(0).normal(scale=0.04, size=(21, 3))


def _check(view, hand: np.ndarray, rotations, translations, expected_up: np.ndarray) -> None:
    up, eye, at = np.asarray(view.up), np.asarray(view.eye), np.asarray(view.look_at)
    expected_up = expected_up / np.linalg.norm(expected_up)
    assert np.allclose(at, hand.mean(axis=0), atol=1e-3)
    assert float(up @ expected_up) > 0.95, (view.up, expected_up)
    assert abs(np.linalg.norm(eye - at) - EYE_DISTANCE_M) < 1e-3
    centres = np.mean([-R.T @ t for R, t in zip(rotations, translations, strict=True)], axis=0)
    assert float((eye - at) @ (centres - at)) > 0, "the eye is on the cameras' side of the hand"
    assert float((eye - at) @ up) > 0, "and above it"
    for R in rotations:  # each camera's image-down axis points against the view's up
        assert float(R[1] @ up) < 0


def test_a_z_up_rig_keeps_z_up_and_a_camera_frame_world_gets_its_minus_y():
    hand_at = np.array([0.0, 0.0, 0.0])
    z_up = np.array([0.0, 0.0, 1.0])
    centres = [np.array([0.6 * np.cos(a), 0.6 * np.sin(a), 0.3]) for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    poses = [_look_at_camera(c, hand_at, z_up) for c in centres]
    hand = _hand(hand_at)
    _check(viewpoint(hand, [R for R, _ in poses], [t for _, t in poses]), hand, [R for R, _ in poses],
           [t for _, t in poses], z_up)
    # The same rig expressed in its first camera's frame (as calibration tools export it): y down
    R0, t0 = poses[0]
    moved = [(R @ R0.T, t - R @ R0.T @ t0) for R, t in poses]
    hand_cam = (R0 @ hand.T).T + t0
    view = viewpoint(hand_cam, [R for R, _ in moved], [t for _, t in moved])
    _check(view, hand_cam, [R for R, _ in moved], [t for _, t in moved], R0 @ z_up)
    assert float(np.asarray(view.up) @ np.array([0.0, -1.0, 0.0])) > 0.85  # the cameras look down 27 degrees


def test_the_real_two_webcam_rig_is_seen_from_its_cameras_side():
    cameras = handpose3d_cameras()
    rotations = [c.R for c in cameras]
    translations = [c.t for c in cameras]
    # a hand 0.5 m in front of the first camera (its optical axis), in the rig's world
    R, t = rotations[0], translations[0]
    hand = _hand(R.T @ (np.array([0.0, 0.0, 0.5]) - t))
    view = viewpoint(hand, rotations, translations)
    _check(view, hand, rotations, translations, -np.mean([R[1] for R in rotations], axis=0))


def test_a_y_down_rig_records_a_scene():
    R = np.eye(3)
    cameras = [SceneCamera("cam0", None, 0.8, 4 / 3, R, np.zeros(3))]
    data = record_scene(SampleScene(vertices=None, faces=None, keypoints=_hand(np.array([0.0, 0.0, 0.5])),
                                    prediction=None, cameras=cameras, label="test"))
    assert len(data) > 100


def test_without_cameras_the_view_is_z_up_and_still_looks_at_the_hand():
    hand = _hand(np.array([0.1, 0.2, 0.3]))
    view = viewpoint(hand, [], [])
    at, eye = np.asarray(view.look_at), np.asarray(view.eye)
    assert view.up == (0.0, 0.0, 1.0)
    assert abs(np.linalg.norm(eye - at) - EYE_DISTANCE_M) < 1e-3 and eye[2] > at[2]
