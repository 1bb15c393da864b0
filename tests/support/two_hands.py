"""Two hands in every view (issue 36): a right and a left hand of the built-in hand model, each moving as in its own
synthetic sequence, rendered together into one green-screen scene at small size, with both hands' ground truth.

The right hand comes from a sequence of `seed`, the left from one of `seed + 1` (same rig); the two are moved
`separation_m` apart along the world's x axis so that they sit side by side, as two hands over a table do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.geometry.camera import Camera
from workers.geometry.projection import project_points
from workers.rendering.scene import MeshPart, render_views
from workers.synth.compositing import camera_image, chroma_key
from workers.synth.generator import FrameRenderer
from workers.synth.plan import SynthConfig

SIDES = ("right", "left")


@dataclass(frozen=True)
class TwoHandFrame:
    """One frame with both hands.

    Attributes:
        images: C (H, W, 3) uint8 RGB, calibration order.
        masks: C (H, W) bool chroma-key foregrounds (both hands and forearms).
        keypoints_3d: side -> (21, 3) metres, world frame.
        keypoints_2d: side -> (C, 21, 2) pixels.
        visible_px: side -> (C,) int, pixels of that hand visible in each view.
    """

    images: list[np.ndarray]
    masks: list[np.ndarray]
    keypoints_3d: dict[str, np.ndarray]
    keypoints_2d: dict[str, np.ndarray]
    visible_px: dict[str, np.ndarray]


def render_two_hands(seed: int, frames: int, width_px: int = 320, separation_m: float = 0.16
                     ) -> tuple[list[Camera], list[TwoHandFrame]]:
    """The rig's cameras and `frames` frames of both hands (see the module's docstring)."""
    renderers = {side: FrameRenderer(SynthConfig(num_sequences=1, frames_per_sequence=frames, seed=seed + k,
                                                 width_px=width_px, side=side)) for k, side in enumerate(SIDES)}
    cameras = list(renderers["right"].cameras)
    look = renderers["right"]._sequence(0)[0]  # the right hand's sequence gives lights and backgrounds
    rendered = {side: r.render(0, 0, frames) for side, r in renderers.items()}
    out = []
    for f in range(frames):
        parts: list[MeshPart] = []
        first_part, keypoints_3d = {}, {}
        for side, sign in zip(SIDES, (-1.0, 1.0), strict=True):
            frame = rendered[side][f]
            # Each hand's own wrist to x = 0, then half the separation to its side.
            shift = np.array([sign * separation_m / 2 - frame.ground_truth.keypoints_3d[0, 0], 0.0, 0.0])
            first_part[side] = len(parts)
            parts += [MeshPart(p.name, p.vertices + shift, p.faces, p.albedo_rgb, p.closed) for p in frame.parts]
            keypoints_3d[side] = frame.ground_truth.keypoints_3d + shift
        views = render_views(parts, cameras, look.shading)
        images = [camera_image(v.color, v.part_ids >= 0, bg, spill=look.spill, spill_width_px=look.spill_width_px,
                               noise=None) for v, bg in zip(views, look.backgrounds, strict=True)]
        out.append(TwoHandFrame(
            images=images, masks=[chroma_key(image) for image in images], keypoints_3d=keypoints_3d,
            keypoints_2d={side: project_points(keypoints_3d[side], cameras)[0] for side in SIDES},
            visible_px={side: np.array([int((v.part_ids == first_part[side]).sum()) for v in views])
                        for side in SIDES}))
    return cameras, out
