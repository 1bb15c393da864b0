"""Linear blend skinning as a chain of small pure functions (after smplx's lbs.py, written anew).

One forward pass with two faces: every function takes numpy arrays or torch tensors (all of one kind) and
returns the same kind (`workers.geometry.arrays`). The torch face is `HandLayer` (workers/handmodel/layer.py,
differentiable, batched buffers); the numpy face is `posed_mesh` (workers/handmodel/posed.py, torch-free for
the API process). torch is never imported by this module.

Shapes: B batch, V vertices, J joints (16), S shape coefficients (10), P pose-corrective inputs
(9 (J - 1) = 135). Units: metres, radians. Frames: the model's rest frame (MANO semantics: each joint's
axis-angle rotation is expressed in the rest-pose frame, relative to its parent).
"""

from __future__ import annotations

import functools

from workers.geometry.arrays import Array, constant_like, copy, eye_like, namespace
from workers.geometry.rotation import axis_angle_to_matrix, skew

__all__ = ["axis_angle_to_matrix", "blend_shapes", "keypoints_from_vertices", "lbs", "pose_features",
           "pose_offsets", "rigid_transforms", "skew", "skin_vertices", "vertices_to_joints"]


def blend_shapes(betas: Array, shapedirs: Array) -> Array:
    """Shape offsets: betas (B, S), shapedirs (V, 3, S) -> (B, V, 3) metres."""
    V, _, S = shapedirs.shape
    return (betas @ shapedirs.reshape(V * 3, S).T).reshape(-1, V, 3)  # one matmul, no tiny batches


def vertices_to_joints(J_regressor: Array, vertices: Array) -> Array:
    """Regress joints: J_regressor (J, V), vertices (B, V, 3) -> (B, J, 3)."""
    return J_regressor @ vertices


def pose_features(rot_mats: Array) -> Array:
    """MANO's pose-corrective input: rot_mats (B, J, 3, 3) -> (B, 9 (J - 1)), (R_j - I) of joints 1..J-1."""
    return (rot_mats[:, 1:] - eye_like(3, rot_mats)).reshape(rot_mats.shape[0], -1)


def pose_offsets(features: Array, posedirs: Array) -> Array:
    """Pose-corrective offsets: features (B, P), posedirs (V, 3, P) -> (B, V, 3) metres."""
    V, _, P = posedirs.shape
    return (features @ posedirs.reshape(V * 3, P).T).reshape(-1, V, 3)


def rigid_transforms(rot_mats: Array, joints: Array, parents: tuple[int, ...]) -> tuple[Array, Array]:
    """Compose joint rotations along the kinematic tree.

    Args:
        rot_mats: (B, J, 3, 3) local rotations (joint 0 = global orientation).
        joints: (B, J, 3) rest-pose joint locations of the shaped model, metres.
        parents: (J,) parent indices, parents[0] = -1, each parent before its children.
    Returns:
        posed_joints: (B, J, 3) joint locations after posing.
        skinning: (B, J, 4, 4) transforms taking rest-pose points to posed points for each joint.
    """
    xp = namespace(joints)
    B, J = joints.shape[:2]
    rel_joints = copy(joints)
    rel_joints[:, 1:] = joints[:, 1:] - joints[:, list(parents[1:])]
    bottom = xp.broadcast_to(constant_like([0.0, 0.0, 0.0, 1.0], joints).reshape(1, 1, 1, 4), (B, J, 1, 4))
    local = xp.concat([xp.concat([rot_mats, rel_joints[..., None]], axis=-1), bottom], axis=-2)  # (B, J, 4, 4)
    # One batched product per tree level (3 for a hand) instead of one per joint: a fit spends its
    # time in per-operation overhead, forward and backward.
    world = copy(local)
    for level in _tree_levels(tuple(parents))[1:]:
        world[:, list(level)] = world[:, [parents[j] for j in level]] @ local[:, list(level)]
    posed_joints = world[..., :3, 3]
    # Remove each joint's rest location so the transform applies to rest-pose vertices directly.
    rest_in_world = xp.einsum("bjik,bjk->bji", world[..., :3, :3], joints)
    skinning = copy(world)
    skinning[..., :3, 3] = posed_joints - rest_in_world
    return posed_joints, skinning


@functools.lru_cache(maxsize=16)
def _tree_levels(parents: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    """Joints grouped by depth in the kinematic tree: ((root,), (children of root), ...)."""
    depth = [0] * len(parents)
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1
    return tuple(tuple(j for j in range(len(parents)) if depth[j] == d) for d in range(max(depth) + 1))


def skin_vertices(vertices: Array, weights: Array, transforms: Array) -> Array:
    """Blend per-joint transforms: vertices (B, V, 3), weights (V, J), transforms (B, J, 4, 4) -> (B, V, 3).

    Written as one matmul plus elementwise products: a batched 3x3 product per vertex (einsum/bmm)
    was the slowest step of a fit on CPU (measured: most of the backward pass).
    """
    B, J = transforms.shape[:2]
    blended = (weights @ transforms[:, :, :3, :].reshape(B, J, 12)).reshape(B, -1, 3, 4)  # (B, V, 3, 4)
    return (blended[..., :3] * vertices[:, :, None, :]).sum(-1) + blended[..., 3]


def lbs(betas: Array, full_pose: Array, v_template: Array, shapedirs: Array, posedirs: Array | None,
        J_regressor: Array, parents: tuple[int, ...], weights: Array) -> tuple[Array, Array]:
    """Shape, pose-correct and skin the template.

    Args:
        betas: (B, S) shape coefficients.
        full_pose: (B, 3 J) axis-angle per joint, radians; joint 0 is the global orientation.
        v_template: (V, 3); shapedirs: (V, 3, S); posedirs: (V, 3, P) or None (no pose correctives);
        J_regressor: (J, V);
        parents: (J,); weights: (V, J).
    Returns:
        vertices: (B, V, 3) posed vertices, metres, rotated about the root joint (no translation).
        joints: (B, J, 3) posed joints.
    """
    v_shaped = v_template + blend_shapes(betas, shapedirs)
    joints_rest = vertices_to_joints(J_regressor, v_shaped)
    rot_mats = axis_angle_to_matrix(full_pose.reshape(full_pose.shape[0], -1, 3))
    v_posed = v_shaped if posedirs is None else v_shaped + pose_offsets(pose_features(rot_mats), posedirs)
    joints_posed, transforms = rigid_transforms(rot_mats, joints_rest, parents)
    return skin_vertices(v_posed, weights, transforms), joints_posed


def keypoints_from_vertices(vertices: Array, J_regressor: Array, tip_ids: Array, keypoint_order: Array) -> Array:
    """FreiHAND's 21 keypoints of posed meshes: the 16 joints regressed from the vertices plus the 5 fingertip
    vertices, in FreiHAND order.

    Args:
        vertices: (B, V, 3) posed vertices, metres.
        J_regressor: (16, V).  tip_ids: (5,) int vertex ids (thumb .. pinky).
        keypoint_order: (21,) int, FREIHAND_FROM_MANO (index into the 16 joints followed by the 5 tips).
    Returns:
        (B, 21, 3) keypoints, same frame and units as `vertices`.
    """
    xp = namespace(vertices)
    regressed = vertices_to_joints(J_regressor, vertices)  # (B, 16, 3)
    return xp.concat([regressed, vertices[:, tip_ids]], axis=1)[:, keypoint_order]
