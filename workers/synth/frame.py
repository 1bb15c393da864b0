"""Render one synthetic multi-view frame: hand + forearm (+ object) over the sequence's background,
and its ground truth (hand parameters, keypoints, vertices, masks, visibility)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.capture.schema import GroundTruth
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points
from workers.rendering.scene import MeshPart, render_views
from workers.rendering.shading import DirectionalLight, ShadingSettings
from workers.synth.backgrounds import evaluation_background, green_screen
from workers.synth.compositing import NoiseBank, camera_image, chroma_key
from workers.synth.motion import hand_axes
from workers.synth.plan import SequencePlan
from workers.synth.props import forearm_mesh, grasp_center, object_mesh, wrist_opening
from workers.synth.visibility import keypoint_visibility, skin_depth_tolerance_m

# Part indices in the rendered scene.
HAND, FOREARM, OBJECT = 0, 1, 2


@dataclass(frozen=True)
class SequenceLook:
    """What stays fixed during a sequence: cameras, per-view backgrounds, lights, skin.

    Attributes:
        plan: the sequence plan.
        cameras: the C views.
        backgrounds: C (H, W, 3) float32 sRGB backgrounds (static cameras see a static scene).
        shading: lights, world frame.
        hand_albedo: (V, 3) float32 linear per-vertex skin albedo.
        skin_rgb: (3,) float32 linear mean skin albedo (forearm).
        spill: green spill strength at the edge (0 off the green screen).
        spill_width_px: how far the spill reaches into the subject, pixels (scales with resolution).
        noise: sensor noise source.
        side: hand side.
    """

    plan: SequencePlan
    cameras: tuple[Camera, ...]
    backgrounds: tuple[np.ndarray, ...]
    shading: ShadingSettings
    hand_albedo: np.ndarray
    skin_rgb: np.ndarray
    spill: float
    spill_width_px: float
    noise: NoiseBank
    side: str = "right"


@dataclass(frozen=True)
class HandState:
    """The posed hand of one frame (world frame, metres; parameters as in GroundTruth)."""

    betas: np.ndarray
    pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray
    vertices: np.ndarray
    keypoints: np.ndarray
    forearm_axis: np.ndarray


@dataclass(frozen=True)
class RenderedFrame:
    """One frame, ready to write.

    Attributes:
        images: camera -> (H, W, 3) uint8 RGB.
        chroma_masks: camera -> (H, W) bool chroma-key foreground (green-screen sequences), else None.
        ground_truth: the frame's ground truth.
        part_ids: camera -> (H, W) int8 visible scene part (HAND, FOREARM, OBJECT; -1 background).
        parts: the scene's meshes (world frame, metres), in part order.
    """

    images: dict[str, np.ndarray]
    chroma_masks: dict[str, np.ndarray] | None
    ground_truth: GroundTruth
    part_ids: dict[str, np.ndarray]
    parts: tuple[MeshPart, ...] = ()


def sequence_lighting(green: bool, rng: np.random.Generator) -> ShadingSettings:
    """Studio LEDs (a key light and a fill, varied colour temperature) on the green screen; a single
    'room or sun' light with more ambient for evaluation sequences. The intensities are normalised so
    that a surface facing every light at once reaches an exposure of 0.85-1.0 (no blown-out skin)."""
    warm = rng.uniform(-0.08, 0.08)
    tint = np.array([1.0 + warm, 1.0, 1.0 - warm])
    key = rng.normal(0, 0.35, 3) + np.array([rng.choice([-0.6, 0.6]), 0.3, -1.0])  # from above
    fill = -key + rng.normal(0, 0.3, 3)
    headlight = 0.12
    if green:
        ambient, strengths, specular = rng.uniform(0.1, 0.16), [rng.uniform(0.8, 1.0), rng.uniform(0.2, 0.35)], 0.1
        directions = [key, fill]
    else:
        ambient, strengths, specular = rng.uniform(0.15, 0.25), [rng.uniform(0.6, 0.95)], 0.05
        directions = [key]
    scale = rng.uniform(0.85, 1.0) / (ambient + sum(strengths) + headlight)
    lights = tuple(DirectionalLight(tuple(d), tuple(scale * k * tint)) for d, k in zip(directions, strengths,
                                                                                      strict=True))
    return ShadingSettings(ambient_rgb=tuple(scale * ambient * tint), lights=lights, headlight=scale * headlight,
                           specular=specular)


def sequence_backgrounds(plan: SequencePlan, cameras: list[Camera] | tuple[Camera, ...]) -> tuple[np.ndarray, ...]:
    """Per-view backgrounds of a sequence, float32 sRGB, deterministic from the plan's seed."""
    out = []
    for c, cam in enumerate(cameras):
        rng = np.random.default_rng([plan.seed, 1, c])
        if plan.green_screen:
            out.append(green_screen(cam.height, cam.width, rng))
        else:
            out.append(evaluation_background(plan.background, cam.height, cam.width, rng))
    return tuple(out)


def scene_parts(look: SequenceLook, hand: HandState, faces: np.ndarray) -> list[MeshPart]:
    """Hand, forearm and (if any) object meshes of one frame, in the order HAND, FOREARM, OBJECT."""
    axes = hand_axes(hand.keypoints, look.side)
    opening = wrist_opening(hand.vertices, hand.keypoints[0], axes.forward, axes.palm)
    fv, ff, fa = forearm_mesh(hand.keypoints[0], hand.forearm_axis, axes.forward, axes.palm, opening,
                              look.plan.forearm, look.skin_rgb)
    parts = [MeshPart("hand", hand.vertices, faces, look.hand_albedo), MeshPart("forearm", fv, ff, fa, closed=True)]
    obj = look.plan.held_object
    if obj is not None:
        center = grasp_center(hand.keypoints, axes.palm, obj)
        ov, of = object_mesh(obj, center, axes.forward, axes.palm)
        parts.append(MeshPart("object", ov, of, np.asarray(obj.rgb, np.float32), closed=True))
    return parts


def render_frame(look: SequenceLook, hand: HandState, faces: np.ndarray, rng: np.random.Generator
                 ) -> RenderedFrame:
    """Render all views of one frame and compute its ground truth.

    Args:
        look: the sequence's fixed appearance.
        hand: the posed hand (vertices (V, 3), keypoints (21, 3), metres, world frame).
        faces: (F, 3) hand mesh faces.
        rng: the frame's generator (sensor noise).
    """
    cameras = list(look.cameras)
    parts = scene_parts(look, hand, faces)
    views = render_views(parts, cameras, look.shading)
    images, chroma, masks, part_maps = {}, {}, {}, {}
    for cam, view, background in zip(cameras, views, look.backgrounds, strict=True):
        image = camera_image(view.color, view.part_ids >= 0, background, spill=look.spill,
                             spill_width_px=look.spill_width_px,
                             noise=look.noise.sample(cam.height, cam.width, rng))
        images[cam.name] = image
        if look.plan.green_screen:
            chroma[cam.name] = chroma_key(image)
        masks[cam.name] = view.part_ids == HAND
        part_maps[cam.name] = view.part_ids
    pixels, depth = project_points(hand.keypoints, cameras)
    visibility = keypoint_visibility(pixels, depth, [v.fragments for v in views], [v.part_ids for v in views],
                                     (HAND, FOREARM), skin_depth_tolerance_m(hand.keypoints, hand.vertices))
    gt = GroundTruth(betas=hand.betas, pose=hand.pose, global_orient=hand.global_orient, transl=hand.transl,
                     keypoints_3d=hand.keypoints, vertices=hand.vertices, keypoints_2d=pixels,
                     visibility=visibility, camera_names=tuple(c.name for c in cameras), hand_masks=masks)
    return RenderedFrame(images=images, chroma_masks=chroma if look.plan.green_screen else None,
                         ground_truth=gt, part_ids=part_maps, parts=tuple(parts))
