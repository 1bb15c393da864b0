"""How big a converted rig is: its span and each camera's distance to the rig's centre.

The centre is the common focus of the optical axes (sanity.common_focus: the point the cameras look at, where
the hand is) when the axes converge on a point in front of every camera, else (near-parallel axes, as in a
stereo pair, whose "focus" may lie anywhere along them) the centroid of the camera centres. A wrong length
unit scales all of these by the same factor, so they are what `calibration convert` prints and what
`formats.common.check_units` judges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.geometry.camera import Camera
from workers.rigs.sanity import common_focus

MIN_CONVERGENCE_DEG = 10.0  # optical axes closer to parallel than this have no well-placed focus


@dataclass(frozen=True)
class RigExtent:
    """A rig's size, in the cameras' length unit (metres for handloop cameras).

    Attributes:
        span: largest distance between two camera centres.
        centre: (3,) the rig's centre, world frame.
        centre_is_focus: True when `centre` is the common focus of the optical axes, False for the centroid.
        distances: per camera name, its centre's distance to `centre`, in camera order.
    """

    span: float
    centre: np.ndarray
    centre_is_focus: bool
    distances: dict[str, float]

    def scaled(self, factor: float) -> RigExtent:
        """The same rig with every length multiplied by `factor`."""
        return RigExtent(self.span * factor, self.centre * factor, self.centre_is_focus,
                         {k: v * factor for k, v in self.distances.items()})

    def lines(self) -> list[str]:
        """Two lines for people, lengths in metres: the span, then each camera's distance to the centre."""
        what = "the common focus of the optical axes" if self.centre_is_focus else "the centroid of the cameras"
        return [f"rig span {self.span:.3f} m",
                f"camera distance to the rig's centre ({what}): "
                + ", ".join(f"{name} {d:.3f} m" for name, d in self.distances.items())]


def rig_extent(cameras: list[Camera]) -> RigExtent:
    """The span and centre distances of `cameras` (at least one), in their length unit."""
    centres = np.stack([c.center_world for c in cameras])
    span = float(max((np.linalg.norm(a - b) for i, a in enumerate(centres) for b in centres[i + 1:]), default=0.0))
    focus = common_focus(cameras)
    axes = np.stack([c.R[2] for c in cameras])
    widest = float(np.degrees(np.arccos(np.clip((axes @ axes.T).min(), -1.0, 1.0))))
    if focus is not None and (widest < MIN_CONVERGENCE_DEG or any((c.R @ focus + c.t)[2] <= 0 for c in cameras)):
        focus = None
    centre = focus if focus is not None else centres.mean(axis=0)
    distances = {c.name: float(np.linalg.norm(x - centre)) for c, x in zip(cameras, centres, strict=True)}
    return RigExtent(span, centre, focus is not None, distances)
