"""Keypoint and joint orders shared by every hand model.

MANO's 16 joints (the kinematic tree) and FreiHAND's 21 keypoints differ in order; FreiHAND adds the
five fingertips as surface vertices. See docs/conventions.md.
"""

from __future__ import annotations

# MANO joint order: wrist, then index, middle, little (pinky), ring, thumb; each base -> tip.
MANO_JOINT_NAMES: tuple[str, ...] = (
    "wrist",
    "index1", "index2", "index3",
    "middle1", "middle2", "middle3",
    "pinky1", "pinky2", "pinky3",
    "ring1", "ring2", "ring3",
    "thumb1", "thumb2", "thumb3",
)  # fmt: skip

# Parent of each MANO joint in the kinematic tree (-1 for the root).
MANO_PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)

NUM_JOINTS = 16
NUM_KEYPOINTS = 21
NUM_BETAS = 10
NUM_POSE = 45  # 15 articulated joints x 3 axis-angle components

# FreiHAND keypoint order: 0 wrist; 1-4 thumb; 5-8 index; 9-12 middle; 13-16 ring; 17-20 pinky.
KEYPOINT_NAMES: tuple[str, ...] = (
    "wrist",
    "thumb_mcp", "thumb_pip", "thumb_dip", "thumb_tip",
    "index_mcp", "index_pip", "index_dip", "index_tip",
    "middle_mcp", "middle_pip", "middle_dip", "middle_tip",
    "ring_mcp", "ring_pip", "ring_dip", "ring_tip",
    "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip",
)  # fmt: skip

# Fingertip vertex order used by every hand model: thumb, index, middle, ring, pinky.
FINGERTIP_ORDER: tuple[str, ...] = ("thumb", "index", "middle", "ring", "pinky")

# FreiHAND's fingertip vertices on MANO's 778-vertex mesh (thumb, index, middle, ring, pinky).
MANO_FINGERTIP_VERTEX_IDS: tuple[int, ...] = (744, 320, 443, 555, 672)

# Index into concat(joints[16], tips[5]) for each FreiHAND keypoint (tips are 16..20 in FINGERTIP_ORDER).
FREIHAND_FROM_MANO: tuple[int, ...] = (
    0,
    13, 14, 15, 16,
    1, 2, 3, 17,
    4, 5, 6, 18,
    10, 11, 12, 19,
    7, 8, 9, 20,
)  # fmt: skip

# The sparse click set of the paper: wrist and the five fingertips.
SPARSE_KEYPOINTS: tuple[int, ...] = (0, 4, 8, 12, 16, 20)

# Skeleton edges (parent, child) in FreiHAND order, for drawing.
SKELETON_EDGES: tuple[tuple[int, int], ...] = tuple(
    (0 if k % 4 == 1 else k - 1, k) for k in range(1, NUM_KEYPOINTS)
)
