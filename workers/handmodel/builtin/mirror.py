"""Left hand = mirror image of the right hand through the plane x = 0.

With M = diag(-1, 1, 1):
- positions (v_template, shapedirs' xyz axis) get x negated; J_regressor and weights are unchanged;
- faces reverse their winding (a reflection turns counter-clockwise into clockwise);
- a rotation R maps to M R M, whose axis-angle is (w_x, -w_y, -w_z): hands_components' columns and
  hands_mean flip the sign of every joint's y and z entries (the MANO left/right convention);
- pose correctives: entry (a, b) of (R - I) maps to m_a m_b times itself, so posedirs[v, c, (j, a, b)]
  is multiplied by m_c m_a m_b.
The rest frame of the left hand therefore has fingers along -x, palm normal +y and thumb toward +z.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from workers.handmodel.arrays import HandModelArrays

_M = np.array([-1.0, 1.0, 1.0])
_POSE_SIGN = np.tile(np.array([1.0, -1.0, -1.0]), 15)  # (45,)


def mirror_arrays(arrays: HandModelArrays, side: str) -> HandModelArrays:
    """The mirror image of `arrays` (any side), labelled `side`; validated."""
    entry_sign = np.einsum("a,b->ab", _M, _M).ravel()  # (9,) sign of (R - I)[a, b]
    pd_sign = _M[None, :, None] * np.tile(entry_sign, 15)[None, None, :]  # (1, 3, 135)
    return replace(
        arrays,
        side=side,
        v_template=arrays.v_template * _M,
        shapedirs=arrays.shapedirs * _M[None, :, None],
        posedirs=arrays.posedirs * pd_sign,
        faces=arrays.faces[:, ::-1].copy(),
        hands_components=arrays.hands_components * _POSE_SIGN[None, :],
        hands_mean=arrays.hands_mean * _POSE_SIGN,
        extras=dict(arrays.extras),
    ).validate()
