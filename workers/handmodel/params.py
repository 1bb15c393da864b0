"""The hand's parameters as one type: `HandParams`, to and from the 61-value vector theta (numpy only).

theta's layout (docs/conventions.md), the one every fit, record, export and payload stores:

    index   0..9    betas          (10,) shape coefficients, unitless
    index  10..54   pose           (45,) articulation, axis-angle radians per joint 1..15, flat-hand mean
                                   (zero = the flat template hand, MANO's `flat_hand_mean=True`)
    index  55..57   global_orient  (3,)  axis-angle radians of the root about the wrist joint, world frame
    index  58..60   transl         (3,)  translation, metres, world frame

Any leading batch shape is allowed: theta (..., 61) gives fields (..., 10), (..., 45), (..., 3), (..., 3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from workers.handmodel.keypoints import NUM_BETAS, NUM_POSE

NUM_PARAMS = NUM_BETAS + NUM_POSE + 3 + 3  # 61


@dataclass(frozen=True, eq=False)
class HandParams:
    """Shape, articulation, global rotation and translation of one hand (or a batch), float64.

    Attributes:
        betas: (..., 10) shape coefficients.
        pose: (..., 45) articulation, axis-angle radians, flat-hand mean.
        global_orient: (..., 3) axis-angle radians about the wrist joint, world frame.
        transl: (..., 3) metres, world frame.
    """

    betas: np.ndarray
    pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray

    BETAS: ClassVar[slice] = slice(0, NUM_BETAS)
    POSE: ClassVar[slice] = slice(NUM_BETAS, NUM_BETAS + NUM_POSE)
    GLOBAL_ORIENT: ClassVar[slice] = slice(NUM_BETAS + NUM_POSE, NUM_BETAS + NUM_POSE + 3)
    TRANSL: ClassVar[slice] = slice(NUM_BETAS + NUM_POSE + 3, NUM_PARAMS)

    @classmethod
    def from_theta(cls, theta: np.ndarray | list) -> HandParams:
        """theta (..., 61) (the layout of the module docstring) -> HandParams; ValueError naming the shape
        when it is not (..., 61) finite numbers."""
        theta = np.asarray(theta, dtype=np.float64)
        if theta.ndim < 1 or theta.shape[-1] != NUM_PARAMS or not np.isfinite(theta).all():
            raise ValueError(f"params must be {NUM_PARAMS} finite numbers (betas 10, pose 45, global_orient 3, "
                             f"transl 3), got shape {theta.shape}")
        return cls(theta[..., cls.BETAS], theta[..., cls.POSE], theta[..., cls.GLOBAL_ORIENT], theta[..., cls.TRANSL])

    @classmethod
    def zeros(cls, *batch: int) -> HandParams:
        """The flat, mean-shape hand at the origin: fields (*batch, n) of zeros."""
        return cls.from_theta(np.zeros((*batch, NUM_PARAMS)))

    def to_theta(self) -> np.ndarray:
        """(..., 61) float64 in the layout of the module docstring."""
        return np.concatenate([np.asarray(a, dtype=np.float64)
                               for a in (self.betas, self.pose, self.global_orient, self.transl)], axis=-1)

    @property
    def full_pose(self) -> np.ndarray:
        """(..., 48) axis-angle radians: global orientation then articulation (joint 0..15)."""
        return np.concatenate([self.global_orient, self.pose], axis=-1)
