"""One sample's 3D scene for reviewers: the fitted mesh, its skeleton and keypoints, MVNet's keypoints,
and the rig's camera frustums showing their images. The rig's world frame, metres; "up" is what the rig's cameras
show as up (a real rig's world is often its first camera's, y down: see `viewpoint`)."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np

from backend.viewer import recorder
from workers.handmodel.keypoints import SKELETON_EDGES

# Per finger, wrist, thumb .. pinky; the 2D overlays get them through frontend/js/keypoint_table.js (generated).
FINGER_RGB = ((120, 120, 120), (230, 57, 70), (244, 162, 97), (42, 157, 143), (69, 123, 157), (157, 78, 221))
SKIN_RGB = (222, 170, 140)
THUMBNAIL_WIDTH_PX = 240


def finger_of(keypoint: int) -> int:
    """0 for the wrist, 1..5 for thumb .. pinky (FreiHAND order)."""
    return 0 if keypoint == 0 else (keypoint - 1) // 4 + 1


@dataclass(frozen=True, eq=False)
class SceneCamera:
    """name; image (h, w, 3) uint8 (a thumbnail); fov_y_rad; aspect (w / h); R (3, 3) world -> camera; t (3,)."""

    name: str
    image: np.ndarray | None
    fov_y_rad: float
    aspect: float
    R: np.ndarray
    t: np.ndarray


@dataclass(frozen=True, eq=False)
class SampleScene:
    """What a recording shows. vertices (V, 3) / faces (F, 3) or None; keypoints (21, 3) metres;
    prediction (21, 3) or None; label: the hand model, shown next to the hand."""

    vertices: np.ndarray | None
    faces: np.ndarray | None
    keypoints: np.ndarray
    prediction: np.ndarray | None
    cameras: list[SceneCamera]
    label: str


def thumbnail(image_bytes: bytes, width: int = THUMBNAIL_WIDTH_PX) -> np.ndarray:
    """Decode an image file and shrink it to `width` pixels (RGB uint8)."""
    from PIL import Image  # deferred: PIL (~45 ms) with the first thumbnail; the API's start-up imports this module

    with Image.open(io.BytesIO(image_bytes)) as img:
        img.draft("RGB", (width, max(1, round(img.height * width / img.width))))  # JPEG: decode at 1/2..1/8 scale
        img = img.convert("RGB")
        if img.width > width:
            img = img.resize((width, max(1, round(img.height * width / img.width))), Image.Resampling.BILINEAR)
        return np.asarray(img, dtype=np.uint8)


def scene_camera(name: str, width: int, height: int, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                 image: np.ndarray | None) -> SceneCamera:
    fov_y = 2.0 * math.atan(height / (2.0 * float(K[1][1])))
    return SceneCamera(name, image, fov_y, width / height, np.asarray(R, float), np.asarray(t, float))


def _skeleton_segments(keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    points = np.stack([[keypoints[a], keypoints[b]] for a, b in SKELETON_EDGES])  # (E, 2, 3)
    colors = np.asarray([[FINGER_RGB[finger_of(b)]] * 2 for _, b in SKELETON_EDGES], dtype=np.uint8)
    return points, colors


@dataclass(frozen=True)
class Viewpoint:
    """Where the 3D view starts, in the rig's world frame (metres): `eye` looks at `look_at` with `up` (unit)."""

    eye: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float]


EYE_DISTANCE_M = 0.45  # a hand (~0.2 m) fills about half of viser's 75-degree view from here


def _unit(v: np.ndarray) -> np.ndarray | None:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-9 and math.isfinite(n) else None


def viewpoint(keypoints: np.ndarray, rotations: list[np.ndarray], translations: list[np.ndarray]) -> Viewpoint:
    """The starting view of a sample's scene, whatever the rig's world frame: a real rig's world is often its
    first camera's (y down, z forward) where a synthetic one's is z up, and a fixed "+z up, eye beside the
    origin" showed a real recording's hand from behind a camera or not at all (issue 38 item 13).

    keypoints (21, 3) metres; rotations R (3, 3) world -> camera and translations t (3,) per camera. Up is
    against the cameras' mean image-down axis (cameras stand upright); the eye is EYE_DISTANCE_M from the
    hand's centre, on the side of the cameras, raised 30 degrees."""
    at = np.asarray(keypoints, dtype=np.float64).mean(axis=0)
    downs = [np.asarray(R, dtype=np.float64)[1] for R in rotations]  # each camera's image y axis in the world
    up = _unit(-np.mean(downs, axis=0)) if downs else None
    up = up if up is not None else np.array([0.0, 0.0, 1.0])
    centres = [-np.asarray(R, dtype=np.float64).T @ np.asarray(t, dtype=np.float64)
               for R, t in zip(rotations, translations, strict=True)]
    toward = np.mean(centres, axis=0) - at if centres else np.zeros(3)
    side = _unit(toward - float(toward @ up) * up)  # the cameras' direction in the horizontal plane
    if side is None:  # no cameras, or cameras straight above or below the hand: any horizontal direction
        side = _frame_with_z(up)[:, 0]
    eye = at + EYE_DISTANCE_M * (math.cos(math.radians(30)) * side + math.sin(math.radians(30)) * up)

    def rounded(v: np.ndarray) -> tuple[float, float, float]:
        return tuple(round(float(x), 4) for x in v)  # type: ignore[return-value]

    return Viewpoint(eye=rounded(eye), look_at=rounded(at), up=rounded(up))


def build(scene, content: SampleScene) -> None:
    """Add `content` to a viser scene (a `viser.SceneApi`), with the rig's up (`viewpoint`) and a floor grid
    under the hand."""
    from viser import transforms  # deferred: viser (~0.5 s) only when a scene is recorded

    view = viewpoint(content.keypoints, [c.R for c in content.cameras], [c.t for c in content.cameras])
    up = np.asarray(view.up)
    scene.set_up_direction(view.up)
    floor = transforms.SO3.from_matrix(_frame_with_z(up))  # the grid's xy plane across the rig's up
    scene.add_grid("/floor", width=1.0, height=1.0, cell_size=0.1, section_size=0.5, plane="xy",
                   wxyz=floor.wxyz, position=tuple(np.asarray(view.look_at) - 0.3 * up))
    if content.vertices is not None and content.faces is not None:
        scene.add_mesh_simple("/fit/mesh", vertices=content.vertices.astype(np.float32),
                              faces=content.faces.astype(np.uint32), color=SKIN_RGB, opacity=0.85, side="double")
    points, colors = _skeleton_segments(content.keypoints)
    scene.add_line_segments("/fit/skeleton", points=points.astype(np.float32), colors=colors, thickness=0.002)
    kp_colors = np.asarray([FINGER_RGB[finger_of(k)] for k in range(21)], dtype=np.uint8)
    scene.add_point_cloud("/fit/keypoints", points=content.keypoints.astype(np.float32), colors=kp_colors,
                          point_size=0.008, point_shape="circle")
    scene.add_label("/fit/label", content.label, position=tuple(content.keypoints[0] + np.array([0.0, 0.0, 0.04])))
    if content.prediction is not None:
        scene.add_point_cloud("/mvnet/keypoints", points=content.prediction.astype(np.float32),
                              colors=(255, 255, 255), point_size=0.006, point_shape="diamond")
    for cam in content.cameras:
        R_world_cam = cam.R.T
        scene.add_camera_frustum(
            f"/cameras/{cam.name}", fov=cam.fov_y_rad, aspect=cam.aspect, scale=0.07, thickness=0.002,
            image=cam.image, format="jpeg", jpeg_quality=80, wxyz=transforms.SO3.from_matrix(R_world_cam).wxyz,
            position=-R_world_cam @ cam.t, color=(40, 40, 40))


def _frame_with_z(z: np.ndarray) -> np.ndarray:
    """A rotation (3, 3) whose third column is the unit vector `z`."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def record_scene(content: SampleScene) -> bytes:
    """The scene as a `.viser` recording."""

    return recorder.record(lambda scene: build(scene, content))
