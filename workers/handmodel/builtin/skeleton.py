"""Rest-pose skeleton of the built-in right hand, from anthropometric proportions.

Rest frame (right hand, metres): the wrist joint at the origin, fingers along +x, palm normal +y (the
palm faces +y, the back of the hand -y), thumb toward +z. This is a right-handed frame: for a right hand
`thumb = fingers x palm_normal`. Joint order and parents are MANO's (`keypoints.MANO_JOINT_NAMES`).

Figures come from /work/shared/HAND_ANATOMY.md: bone lengths as fractions of hand length (Buchholz et
al. 1992), MCP positions on the knuckle arc, finger breadths (Greiner 1991) with depth = 0.87 x width.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

# Finger order used inside the builtin package (FINGERTIP_ORDER): thumb, index, middle, ring, pinky.
FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "pinky")
# MANO joint ids of each finger's three joints (base -> tip), in FINGERS order.
FINGER_JOINTS: tuple[tuple[int, int, int], ...] = ((13, 14, 15), (1, 2, 3), (4, 5, 6), (10, 11, 12), (7, 8, 9))

# Segment lengths as fractions of hand length (HL): the three bones each joint drives, base -> tip
# (thumb: metacarpal, proximal, distal incl. pad; fingers: proximal, middle, distal incl. pad).
_SEGMENT_FRACTIONS = {
    "thumb": (0.251, 0.196, 0.158),
    "index": (0.245, 0.143, 0.097),
    "middle": (0.266, 0.170, 0.108),
    "ring": (0.244, 0.165, 0.107),
    "pinky": (0.204, 0.117, 0.093),
}
# Base joint position: x in HL, z in joint-spacing breadth units (positive toward the thumb), y metres
# toward the palm (the transverse metacarpal arch puts the outer knuckles slightly palmar).
_BASE_POSITIONS = {
    "thumb": (0.073, 0.200, 0.009),
    "index": (0.447, 0.251, 0.002),
    "middle": (0.446, 0.000, 0.000),
    "ring": (0.409, -0.206, 0.0015),
    "pinky": (0.368, -0.402, 0.004),
}
# Rest direction of each bone as (radial angle toward +z, palmar angle toward +y) in degrees. The
# fingers are spread a little (like MANO's template) so that the closed surface keeps gaps between them.
_BONE_ANGLES_DEG = {
    "thumb": ((40.0, 24.0), (26.0, 12.0), (16.0, 6.0)),
    "index": ((9.0, 0.0), (9.0, 0.0), (9.0, 0.0)),
    "middle": ((0.0, 0.0), (0.0, 0.0), (0.0, 0.0)),
    "ring": ((-9.0, 0.0), (-9.0, 0.0), (-9.0, 0.0)),
    "pinky": ((-19.0, 0.0), (-19.0, 0.0), (-19.0, 0.0)),
}
# Lateral radii (half breadths, metres at HL = 0.19 m) at base, second joint, third joint, tip.
_RADII = {
    "thumb": (0.0135, 0.0112, 0.0104, 0.0090),
    "index": (0.0100, 0.0098, 0.0086, 0.0076),
    "middle": (0.0102, 0.0100, 0.0088, 0.0078),
    "ring": (0.0096, 0.0094, 0.0083, 0.0073),
    "pinky": (0.0086, 0.0084, 0.0074, 0.0065),
}
# Thumb pronation about its own axis at rest (degrees): its nail faces radially-dorsally.
THUMB_PRONATION_DEG = 70.0
DEPTH_RATIO = 0.87  # finger depth / breadth (Nag et al. 2003)


@dataclass(frozen=True)
class HandProportions:
    """Knobs of the procedural hand; every shape direction perturbs one or more of them.

    Attributes:
        hand_length_m: wrist crease to middle fingertip at scale 1 (metres).
        size: uniform scale of the whole hand about the wrist.
        palm_length: scale of the palm along the fingers (x).
        palm_breadth: scale of the palm across (z): knuckle spacing and palm width.
        palm_thickness: scale of the palm's depth (y).
        finger_length: (4,) scale of the phalanges of index, middle, ring, pinky.
        thumb_length: scale of the thumb's three segments.
        finger_thickness: scale of the finger and thumb radii.
    """

    hand_length_m: float = 0.19
    size: float = 1.0
    palm_length: float = 1.0
    palm_breadth: float = 1.0
    palm_thickness: float = 1.0
    finger_length: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    thumb_length: float = 1.0
    finger_thickness: float = 1.0

    def with_finger_length(self, scales: tuple[float, float, float, float]) -> HandProportions:
        return replace(self, finger_length=tuple(float(s) for s in scales))


# Breadth unit for knuckle spacing (metres at HL 0.19): wider than the 0.085 m skin breadth because
# Buchholz's fractions place joint centres; with the soft tissue on both sides the palm is ~0.085 wide.
_SPACING_BREADTH_M = 0.094


def _direction(radial_deg: float, palmar_deg: float) -> np.ndarray:
    """Unit vector from +x turned `radial_deg` toward +z and then `palmar_deg` toward +y."""
    a, b = np.deg2rad(radial_deg), np.deg2rad(palmar_deg)
    return np.array([np.cos(b) * np.cos(a), np.sin(b), np.cos(b) * np.sin(a)])


def _frame(t: np.ndarray, twist_deg: float = 0.0) -> np.ndarray:
    """Rotation (3, 3) with columns (along t, lateral, palmar): palmar = +y made orthogonal to t,
    then both turned by `twist_deg` about t (positive: palmar turns toward -z, the ulnar side)."""
    t = t / np.linalg.norm(t)
    p = np.array([0.0, 1.0, 0.0]) - t[1] * t
    p /= np.linalg.norm(p)
    lat = np.cross(p, t)  # radial (+z) for t = +x
    c, s = np.cos(np.deg2rad(twist_deg)), np.sin(np.deg2rad(twist_deg))
    lat, p = c * lat + s * p, c * p - s * lat
    return np.stack([t, lat, p], axis=1)


@dataclass(frozen=True)
class Skeleton:
    """Rest-pose skeleton of the right hand in the rest frame (metres).

    Attributes:
        joints: (16, 3) joint centres in MANO order.
        tips: (5, 3) fingertip end points (skin surface) in FINGERS order.
        frames: (16, 3, 3) per-joint rotation, columns (bone direction, lateral, palmar); identity for the
            wrist. Bone j runs from joint j to its child (or to the fingertip for the last joints).
        radii: (5, 4) lateral radii at base, joint 2, joint 3 and tip, FINGERS order (metres).
        scales: (16, 3) scale of each joint's bone in its own frame relative to scale-1 proportions
            (used by the shape warp): (along, lateral, palmar) for fingers; (x, y, z) for the wrist.
        proportions: the proportions this skeleton was built from.
    """

    joints: np.ndarray
    tips: np.ndarray
    frames: np.ndarray
    radii: np.ndarray
    scales: np.ndarray
    proportions: HandProportions = field(default_factory=HandProportions)

    def chain(self, finger: int) -> np.ndarray:
        """(4, 3) points base joint, joint 2, joint 3, tip of finger `finger` (FINGERS index)."""
        return np.concatenate([self.joints[list(FINGER_JOINTS[finger])], self.tips[finger : finger + 1]])


def build_skeleton(props: HandProportions | None = None) -> Skeleton:
    """Joint centres, fingertip points, bone frames and radii of the right hand for `props`."""
    props = props or HandProportions()
    hl = props.hand_length_m * props.size
    root_scale = np.array([props.palm_length, props.palm_thickness, props.palm_breadth]) * props.size
    joints = np.zeros((16, 3))
    tips = np.zeros((5, 3))
    frames = np.tile(np.eye(3), (16, 1, 1))
    scales = np.ones((16, 3))
    scales[0] = root_scale
    radii = np.zeros((5, 4))
    scale_hl = 0.19  # the unscaled tables are written for HL = 0.19 m
    for f, name in enumerate(FINGERS):
        bx, bz, by = _BASE_POSITIONS[name]
        base = np.array([bx * scale_hl, by, bz * _SPACING_BREADTH_M]) * (props.hand_length_m / scale_hl)
        base = base * root_scale
        length_scale = props.thumb_length if f == 0 else props.finger_length[f - 1]
        point = base
        ids = FINGER_JOINTS[f]
        twist = THUMB_PRONATION_DEG if f == 0 else 0.0
        for k in range(3):
            t = _direction(*_BONE_ANGLES_DEG[name][k])
            frames[ids[k]] = _frame(t, twist)
            scales[ids[k]] = props.size * np.array(
                [length_scale, props.finger_thickness, props.finger_thickness]
            )
            joints[ids[k]] = point
            point = point + _SEGMENT_FRACTIONS[name][k] * hl * length_scale * t
        tips[f] = point
        radii[f] = np.asarray(_RADII[name]) * props.finger_thickness * hl / scale_hl
    return Skeleton(joints=joints, tips=tips, frames=frames, radii=radii, scales=scales, proportions=props)
