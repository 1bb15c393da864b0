"""A contact sheet of one frame: every view in a grid, with the ground-truth keypoints and skeleton
(coloured per finger; hollow where the keypoint is not visible in that view) and optional mask outlines."""

from __future__ import annotations

import math

import cv2
import numpy as np

from workers.capture.reader import load_frame_images, load_frame_masks, load_ground_truth
from workers.capture.schema import Capture, CaptureError, FrameRef
from workers.handmodel.keypoints import SKELETON_EDGES

# RGB per finger: thumb, index, middle, ring, pinky; the wrist is white.
FINGER_COLORS: tuple[tuple[int, int, int], ...] = (
    (255, 64, 64), (255, 200, 0), (64, 220, 64), (0, 170, 255), (200, 80, 255))
WRIST_COLOR = (255, 255, 255)


def keypoint_color(k: int) -> tuple[int, int, int]:
    """Drawing colour (RGB) of FreiHAND keypoint k: white for the wrist, else its finger's colour."""
    return WRIST_COLOR if k == 0 else FINGER_COLORS[(k - 1) // 4]


def draw_hand(image: np.ndarray, keypoints_px: np.ndarray, visible: np.ndarray | None = None,
              scale: float = 1.0) -> np.ndarray:
    """Draw a 21-keypoint skeleton on a copy of `image`.

    Args:
        image: (H, W, 3) uint8 RGB.
        keypoints_px: (21, 2) pixels in `image` coordinates.
        visible: (21,) bool; invisible keypoints are drawn hollow (None = all filled).
        scale: line and marker size factor.
    Returns:
        (H, W, 3) uint8 RGB.
    """
    out = np.ascontiguousarray(image.copy())
    thickness = max(1, round(scale))
    radius = max(2, round(2 * scale))
    shift = 4  # sub-pixel drawing: coordinates in 1/16 px
    pts = np.rint(np.nan_to_num(keypoints_px, nan=-1e4) * (1 << shift)).astype(np.int64)
    for parent, child in SKELETON_EDGES:
        cv2.line(out, tuple(int(v) for v in pts[parent]), tuple(int(v) for v in pts[child]),
                 keypoint_color(child), thickness, cv2.LINE_AA, shift)
    for k in range(len(pts)):
        filled = visible is None or bool(visible[k])
        cv2.circle(out, tuple(int(v) for v in pts[k]), radius << shift, keypoint_color(k),
                   -1 if filled else thickness, cv2.LINE_AA, shift)
    # Blend so that the hand stays visible under the drawing.
    return cv2.addWeighted(out, 0.75, np.ascontiguousarray(image), 0.25, 0.0)


def _outline(image: np.ndarray, mask: np.ndarray, color: tuple[int, int, int]) -> None:
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(image, contours, -1, color, 1, cv2.LINE_AA)


def _zoom_box(keypoints_px: np.ndarray, width: int, height: int, margin: float = 1.6,
              min_side_px: int = 48) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) crop around the keypoints with the camera's aspect ratio, inside the image."""
    pts = keypoints_px[np.all(np.isfinite(keypoints_px), axis=1)]
    if not len(pts):
        return 0, 0, width, height
    centre = (pts.min(0) + pts.max(0)) / 2
    half_w = max(float(np.ptp(pts[:, 0])), float(np.ptp(pts[:, 1])) * width / height, min_side_px) * margin / 2
    half_w = min(half_w, width / 2)
    half_h = half_w * height / width
    x0 = int(np.clip(round(centre[0] - half_w), 0, width - 2 * half_w))
    y0 = int(np.clip(round(centre[1] - half_h), 0, height - 2 * half_h))
    return x0, y0, x0 + round(2 * half_w), y0 + round(2 * half_h)


def preview_frame(capture: Capture, frame: FrameRef, *, tile_width: int = 480, columns: int = 4,
                  outline_masks: bool = False, zoom: bool = False) -> np.ndarray:
    """All views of `frame` in a grid, annotated with ground truth when the capture has it.

    Args:
        capture: the capture.
        frame: one of its frames.
        tile_width: width of each tile, pixels (views are resized to it).
        columns: tiles per row.
        outline_masks: outline the chroma-key mask (cyan) and the ground-truth hand mask (magenta).
        zoom: crop each view around its ground-truth keypoints (needs ground truth).
    Returns:
        (rows * tile_h, columns * tile_width, 3) uint8 RGB.
    """
    images = load_frame_images(frame, capture.cameras)
    gt = load_ground_truth(frame, capture.hand_model.num_vertices) if frame.ground_truth_path else None
    masks = load_frame_masks(frame) if outline_masks else {}
    tiles = []
    tile_h = max(round(tile_width * c.height / c.width) for c in capture.cameras)
    for cam in capture.cameras:
        image = images[cam.name]
        offset = np.zeros(2)
        view_masks = {"chroma": masks.get(cam.name), "hand": gt.hand_masks.get(cam.name) if gt else None}
        keypoints = visible = None
        if gt is not None:
            idx = gt.camera_names.index(cam.name)
            keypoints, visible = gt.keypoints_2d[idx], gt.visibility[idx]
            if zoom:
                x0, y0, x1, y1 = _zoom_box(keypoints, cam.width, cam.height)
                image, offset = image[y0:y1, x0:x1], np.array([x0, y0])
                view_masks = {k: None if m is None else m[y0:y1, x0:x1] for k, m in view_masks.items()}
        s = tile_width / image.shape[1]
        size = (tile_width, round(image.shape[0] * s))
        tile = cv2.resize(image, size, interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        if outline_masks:
            for key, color in (("chroma", (0, 255, 255)), ("hand", (255, 0, 255))):
                if view_masks[key] is not None:
                    resized = cv2.resize(view_masks[key].astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
                    _outline(tile, resized > 0, color)
        if keypoints is not None:
            # Pixel-centre convention: u' = s (u - offset + 0.5) - 0.5.
            tile = draw_hand(tile, s * (keypoints - offset + 0.5) - 0.5, visible, scale=max(tile_width / 480, 0.6))
        cv2.putText(tile, cam.name, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        canvas = np.zeros((tile_h, tile_width, 3), np.uint8)
        canvas[:tile.shape[0]] = tile[:tile_h]
        tiles.append(canvas)
    rows = math.ceil(len(tiles) / columns)
    tiles += [np.zeros_like(tiles[0])] * (rows * columns - len(tiles))
    grid = np.concatenate([np.concatenate(tiles[r * columns:(r + 1) * columns], axis=1) for r in range(rows)])
    return grid


def find_frame(capture: Capture, frame_index: int, sequence_id: str | None = None) -> FrameRef:
    """The frame `frame_index` of `sequence_id` (default: the first sequence); CaptureError if absent."""
    if not capture.sequences:
        raise CaptureError(f"{capture.root}: the capture has no sequences")
    try:
        seq = capture.sequence(sequence_id) if sequence_id else capture.sequences[0]
    except KeyError as exc:
        raise CaptureError(f"{capture.root}: {exc.args[0]}") from None
    if not 0 <= frame_index < len(seq.frames):
        raise CaptureError(f"{capture.root}: sequence {seq.id!r} has frames 0..{len(seq.frames) - 1}, "
                           f"not {frame_index}")
    return seq.frames[frame_index]
