"""Random but well-formed MANO-like arrays, for tests that must not depend on a particular hand."""

from __future__ import annotations

import numpy as np

from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.keypoints import MANO_PARENTS


def random_hand_arrays(num_vertices: int = 120, seed: int = 0, pose_correctives: bool = True) -> HandModelArrays:
    """A skeleton along +x with vertices scattered around it; weights and regressor normalised."""
    rng = np.random.default_rng(seed)
    joints = np.zeros((16, 3))
    for j in range(1, 16):
        finger = (j - 1) // 3
        joints[j] = joints[MANO_PARENTS[j]] + [0.03, 0.02 * (finger - 2) if j % 3 == 1 else 0.0, 0.0]
    owner = rng.integers(0, 16, num_vertices)
    v_template = joints[owner] + rng.normal(0, 0.008, (num_vertices, 3))
    weights = rng.random((num_vertices, 16)) ** 4
    weights[np.arange(num_vertices), owner] += 2.0
    weights /= weights.sum(1, keepdims=True)
    J_regressor = np.zeros((16, num_vertices))
    for j in range(16):
        ids = np.flatnonzero(owner == j)
        ids = ids if len(ids) else rng.integers(0, num_vertices, 3)
        J_regressor[j, ids] = rng.random(len(ids)) + 0.5
    J_regressor /= J_regressor.sum(1, keepdims=True)
    posedirs = rng.normal(0, 1e-3, (num_vertices, 3, 135)) if pose_correctives else np.zeros((num_vertices, 3, 135))
    components = np.linalg.qr(rng.normal(size=(45, 45)))[0].T
    return HandModelArrays(
        name="random-test-hand",
        is_mano=False,
        side="right",
        v_template=v_template,
        shapedirs=rng.normal(0, 2e-3, (num_vertices, 3, 10)),
        posedirs=posedirs,
        J_regressor=J_regressor,
        weights=weights,
        parents=np.asarray(MANO_PARENTS),
        faces=rng.integers(0, num_vertices, (200, 3)),
        hands_components=components,
        hands_mean=rng.normal(0, 0.1, 45),
        fingertip_vertex_ids=rng.choice(num_vertices, 5, replace=False),
    ).validate()
