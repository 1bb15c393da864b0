"""Seeded sampler of plausible hand articulations, built from anatomical joint angles.

Poses are written as (flex, abduct, twist) angles per joint (see `limits.py`) and converted to MANO
axis-angle through the anatomical frames of the hand model at hand, so the same poses work for the
built-in hand and for real MANO files (right or left).

Couplings applied to every random sample (HAND_ANATOMY.md):
- DIP flexion = 2/3 PIP flexion (Lin, Wu & Huang 2000), +- a few degrees;
- neighbouring MCP flexions differ by at most 30 deg, unless the base gesture itself separates them
  more (counting and sign gestures hold single fingers out on purpose): then the gap is not widened;
- random MCP spread shrinks as the MCP flexes.
Every pose is clipped to the joint limits.

Shapes: N poses; poses (N, 45) float64 axis-angle radians in the model's rest frame (MANO joint order
1..15, full articulation: hands_mean is NOT to be added again).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.limits import NUM_ARTICULATED, JointFrames, angles_to_pose, joint_frames

# Rows of the (15, 3) angle array per finger: MANO joint id - 1.
_ROWS = {"index": (0, 1, 2), "middle": (3, 4, 5), "pinky": (6, 7, 8), "ring": (9, 10, 11), "thumb": (12, 13, 14)}
_LONG_FINGERS = ("index", "middle", "ring", "pinky")
MCP_COUPLING_DEG = 30.0

# Finger spec (degrees): (MCP flex, MCP abduction (radial +), PIP flex); DIP = 2/3 PIP.
# Thumb spec (degrees): (CMC flex, CMC abduction, CMC twist, MCP flex, IP flex).
_FOLDED = (85.0, 0.0, 100.0)
_THUMB_OVER = (50.0, 0.0, -20.0, 40.0, 30.0)  # thumb folded over the middle phalanges
_POSES: dict[str, dict[str, tuple[float, ...]]] = {
    "flat": {},
    "relaxed": {"index": (15, 0, 15), "middle": (20, 0, 20), "ring": (25, 0, 25), "pinky": (30, 0, 30),
                "thumb": (10, 5, -5, 10, 10)},
    "fist": {"index": (85, -6, 100), "middle": (88, 0, 100), "ring": (90, 5, 100), "pinky": (90, 10, 100),
             "thumb": (50, 0, -20, 40, 30)},
    "count_1": {"index": (0, 0, 0), "middle": _FOLDED, "ring": _FOLDED, "pinky": _FOLDED, "thumb": _THUMB_OVER},
    "count_2": {"index": (0, 6, 0), "middle": (0, -6, 0), "ring": _FOLDED, "pinky": _FOLDED,
                "thumb": (50, 0, -20, 40, 30)},
    "count_3": {"index": (0, 5, 0), "middle": (0, 0, 0), "ring": (0, -5, 0), "pinky": _FOLDED,
                "thumb": (55, 0, -20, 40, 30)},
    "count_4": {"index": (0, 5, 0), "middle": (0, 0, 0), "ring": (0, -5, 0), "pinky": (0, -8, 0),
                "thumb": (55, 5, -20, 50, 30)},
    "count_5": {"index": (0, 12, 0), "middle": (0, 0, 0), "ring": (0, -10, 0), "pinky": (0, -20, 0),
                "thumb": (-20, 15, 0, 0, 0)},
    "pinch": {"index": (40, 0, 45), "middle": (30, 0, 40), "ring": (35, 0, 45), "pinky": (40, 0, 50),
              "thumb": (30, 15, -30, 30, 15)},
    "tripod": {"index": (40, -3, 45), "middle": (42, -5, 45), "ring": (50, 0, 60), "pinky": (55, 0, 65),
               "thumb": (35, 15, -30, 25, 15)},
    "cylinder_grasp": {"index": (50, -5, 65), "middle": (55, 0, 70), "ring": (60, 5, 70),
                       "pinky": (65, 8, 70), "thumb": (25, 30, -25, 20, 15)},
    "sphere_grasp": {"index": (35, 10, 40), "middle": (35, 0, 40), "ring": (35, -8, 40),
                     "pinky": (35, -15, 40), "thumb": (15, 40, -30, 15, 10)},
    "disc_grasp": {"index": (30, 15, 25), "middle": (30, 0, 25), "ring": (30, -12, 25),
                   "pinky": (30, -22, 25), "thumb": (0, 40, -20, 10, 10)},
    "asl_a": {"index": _FOLDED, "middle": _FOLDED, "ring": _FOLDED, "pinky": _FOLDED,
              "thumb": (0, 5, -5, 5, 5)},
    "asl_b": {"index": (0, -6, 0), "middle": (0, 0, 0), "ring": (0, 6, 0), "pinky": (0, 12, 0),
              "thumb": (50, 5, -15, 45, 20)},
    "asl_l": {"index": (0, 0, 0), "middle": _FOLDED, "ring": _FOLDED, "pinky": _FOLDED,
              "thumb": (-20, 10, 0, 0, 0)},
    "asl_y": {"index": _FOLDED, "middle": _FOLDED, "ring": _FOLDED, "pinky": (0, -20, 0),
              "thumb": (-20, 10, 0, 0, 0)},
    "asl_i": {"index": _FOLDED, "middle": _FOLDED, "ring": _FOLDED, "pinky": (0, 0, 0), "thumb": _THUMB_OVER},
    "asl_o": {"index": (40, 0, 60), "middle": (40, 0, 60), "ring": (40, 0, 60), "pinky": (40, 0, 60),
              "thumb": (35, 20, -35, 25, 25)},
    "thumbs_up": {"index": _FOLDED, "middle": _FOLDED, "ring": _FOLDED, "pinky": _FOLDED,
                  "thumb": (-10, 15, 0, 0, 0)},
}
CANONICAL_NAMES: tuple[str, ...] = tuple(_POSES)


def _angles_from_spec(spec: dict[str, tuple[float, ...]]) -> np.ndarray:
    """(15, 3) radians from a finger/thumb spec in degrees."""
    a = np.zeros((NUM_ARTICULATED, 3))
    for name in _LONG_FINGERS:
        mcp, abd, pip = spec.get(name, (0.0, 0.0, 0.0))
        r = _ROWS[name]
        a[r[0]] = (mcp, abd, 0.0)
        a[r[1], 0] = pip
        a[r[2], 0] = 2.0 / 3.0 * pip
    cmc_f, cmc_a, cmc_t, mcp, ip = spec.get("thumb", (0.0, 0.0, 0.0, 0.0, 0.0))
    r = _ROWS["thumb"]
    a[r[0]] = (cmc_f, cmc_a, cmc_t)
    a[r[1], 0] = mcp
    a[r[2], 0] = ip
    return np.deg2rad(a)


def canonical_angles() -> dict[str, np.ndarray]:
    """Named canonical poses as anatomical angles: name -> (15, 3) radians (flex, abduct, twist)."""
    return {name: _angles_from_spec(spec) for name, spec in _POSES.items()}


def apply_couplings(angles: np.ndarray, base: np.ndarray, frames: JointFrames) -> np.ndarray:
    """Enforce DIP ~ 2/3 PIP, the MCP-neighbour rule relative to `base` (both (N, 15, 3) radians), and
    the joint limits; returns a new (N, 15, 3) array."""
    a = angles.copy()
    lim = np.deg2rad(MCP_COUPLING_DEG)
    order = ("index", "middle", "ring", "pinky")
    for name in order:
        r = _ROWS[name]
        a[:, r[1], 0] = np.clip(a[:, r[1], 0], frames.lower_rad[r[1], 0], frames.upper_rad[r[1], 0])
        target = 2.0 / 3.0 * a[:, r[1], 0]
        a[:, r[2], 0] = target + np.clip(a[:, r[2], 0] - target, -np.deg2rad(6), np.deg2rad(6))
    for _ in range(4):  # pairwise projections, repeated so that all three pairs hold together
        for left, right in itertools.pairwise(order):
            i, k = _ROWS[left][0], _ROWS[right][0]
            allowed = np.maximum(lim, np.abs(base[:, i, 0] - base[:, k, 0]))
            mean = 0.5 * (a[:, i, 0] + a[:, k, 0])
            diff = np.clip(a[:, i, 0] - a[:, k, 0], -allowed, allowed)
            a[:, i, 0], a[:, k, 0] = mean + 0.5 * diff, mean - 0.5 * diff
    margin = 1e-4
    return np.clip(a, frames.lower_rad + margin, frames.upper_rad - margin)


class PoseSampler:
    """Canonical poses and seeded random articulations for one hand model (via its JointFrames)."""

    def __init__(self, frames: JointFrames, names: Sequence[str] | None = None) -> None:
        """frames: anatomical frames of the model; names: canonical poses to draw from (default all)."""
        self.frames = frames
        canon = canonical_angles()
        unknown = set(names or ()) - set(canon)
        if unknown:
            raise ValueError(f"unknown canonical poses: {sorted(unknown)}")
        self.names: tuple[str, ...] = tuple(names) if names else tuple(canon)
        self._canon = np.stack([canon[n] for n in self.names])  # (K, 15, 3)

    def canonical_poses(self) -> dict[str, np.ndarray]:
        """name -> (45,) axis-angle pose (radians, rest frame)."""
        poses = angles_to_pose(self._canon, self.frames)
        return {n: poses[i] for i, n in enumerate(self.names)}

    def sample_angles(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 15, 3) radians: random canonical poses, blends of two, and perturbations, coupled."""
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        K = len(self.names)
        first = rng.integers(0, K, size=n)
        second = rng.integers(0, K, size=n)
        w = rng.uniform(0.0, 1.0, size=n) * (rng.uniform(size=n) < 0.5)
        base = (1 - w)[:, None, None] * self._canon[first] + w[:, None, None] * self._canon[second]
        deg = np.pi / 180.0
        noise = np.zeros_like(base)
        curl = rng.normal(0.0, 10.0 * deg, size=(n, 5))  # per-finger curl, shared by its joints
        for f, name in enumerate(("index", "middle", "ring", "pinky", "thumb")):
            r = _ROWS[name]
            noise[:, r, 0] += curl[:, f : f + 1] * (np.array([1.0, 0.8, 0.6]) if f < 4 else 0.6)
        noise[:, :, 0] += rng.normal(0.0, 5.0 * deg, size=(n, NUM_ARTICULATED))
        noise[:, :, 1] += rng.normal(0.0, 4.0 * deg, size=(n, NUM_ARTICULATED))
        noise[:, :, 2] += rng.normal(0.0, 2.0 * deg, size=(n, NUM_ARTICULATED))
        thumb = list(_ROWS["thumb"])
        noise[:, thumb] += rng.normal(0.0, 5.0 * deg, size=(n, 3, 3))
        mcp_rows = [_ROWS[name][0] for name in _LONG_FINGERS]
        flex = np.clip((base[:, mcp_rows, 0] + noise[:, mcp_rows, 0]) / (90 * deg), 0.0, 1.0)
        noise[:, mcp_rows, 1] *= 1.0 - 0.7 * flex  # spread shrinks as the MCP flexes
        scale = rng.uniform(0.0, 1.0, size=(n, 1, 1)) < 0.15  # some samples stay exactly canonical
        return apply_couplings(base + np.where(scale, 0.0, noise), base, self.frames)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 45) axis-angle poses (radians, rest frame), deterministic for a given rng state."""
        return angles_to_pose(self.sample_angles(n, rng), self.frames)

    def pose_bank(self, n: int, seed: int = 0) -> np.ndarray:
        """(n, 45) poses: the canonical poses first, then seeded samples (for nearest-neighbour priors)."""
        canon = np.stack(list(self.canonical_poses().values()))[:n]
        rest = self.sample(max(n - canon.shape[0], 0), np.random.default_rng(seed))
        return np.concatenate([canon, rest])


def sampler_for(arrays: HandModelArrays) -> PoseSampler:
    """A PoseSampler for the hand model `arrays` (any model: built-in or MANO, right or left)."""
    return PoseSampler(joint_frames(arrays))


def canonical_poses(arrays: HandModelArrays) -> dict[str, np.ndarray]:
    """Named canonical poses: name -> (45,) axis-angle radians for `arrays`."""
    return sampler_for(arrays).canonical_poses()


def sample(n: int, rng: np.random.Generator, arrays: HandModelArrays) -> np.ndarray:
    """(n, 45) random plausible poses for `arrays`, drawn from `rng`."""
    return sampler_for(arrays).sample(n, rng)


def pose_bank(n: int, seed: int = 0, *, arrays: HandModelArrays) -> np.ndarray:
    """(n, 45) pose bank for `arrays`: canonical poses then samples from `seed`."""
    return sampler_for(arrays).pose_bank(n, seed)
