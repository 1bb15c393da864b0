"""Linear blend skinning as a chain of small pure functions (after smplx's lbs.py, written anew).

Shapes: B batch, V vertices, J joints (16), S shape coefficients (10), P pose-corrective inputs
(9 (J - 1) = 135). Units: metres, radians. Frames: the model's rest frame (MANO semantics: each joint's
axis-angle rotation is expressed in the rest-pose frame, relative to its parent).
"""

from __future__ import annotations

import functools

import torch


def blend_shapes(betas: torch.Tensor, shapedirs: torch.Tensor) -> torch.Tensor:
    """Shape offsets: betas (B, S), shapedirs (V, 3, S) -> (B, V, 3) metres."""
    V, _, S = shapedirs.shape
    return (betas @ shapedirs.reshape(V * 3, S).T).reshape(-1, V, 3)  # one matmul, no tiny batches


def vertices_to_joints(J_regressor: torch.Tensor, vertices: torch.Tensor) -> torch.Tensor:
    """Regress joints: J_regressor (J, V), vertices (B, V, 3) -> (B, J, 3)."""
    return J_regressor @ vertices


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices: v (..., 3) -> (..., 3, 3) with skew(v) @ w = v x w."""
    zero = torch.zeros_like(v[..., 0])
    x, y, z = v.unbind(-1)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*v.shape[:-1], 3, 3)


def axis_angle_to_matrix(rot_vecs: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula: axis-angle (..., 3) radians -> rotation matrices (..., 3, 3).

    R = I + a(t) K + b(t) K^2 with K = skew(r), a = sin t / t, b = (1 - cos t) / t^2, t = |r|; both
    coefficients switch to their Taylor series near t = 0 so values and gradients stay finite there.
    """
    angle2 = (rot_vecs * rot_vecs).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    small = angle2 < 1e-6
    safe2 = torch.where(small, torch.ones_like(angle2), angle2)
    safe = safe2.sqrt()
    a = torch.where(small, 1 - angle2 / 6 + angle2 * angle2 / 120, torch.sin(safe) / safe)
    b = torch.where(small, 0.5 - angle2 / 24 + angle2 * angle2 / 720, (1 - torch.cos(safe)) / safe2)
    K = skew(rot_vecs)
    eye = torch.eye(3, dtype=rot_vecs.dtype, device=rot_vecs.device).expand_as(K)
    return eye + a * K + b * (K @ K)


def pose_features(rot_mats: torch.Tensor) -> torch.Tensor:
    """MANO's pose-corrective input: rot_mats (B, J, 3, 3) -> (B, 9 (J - 1)), (R_j - I) of joints 1..J-1."""
    eye = torch.eye(3, dtype=rot_mats.dtype, device=rot_mats.device)
    return (rot_mats[:, 1:] - eye).flatten(1)


def pose_offsets(features: torch.Tensor, posedirs: torch.Tensor) -> torch.Tensor:
    """Pose-corrective offsets: features (B, P), posedirs (V, 3, P) -> (B, V, 3) metres."""
    V, _, P = posedirs.shape
    return (features @ posedirs.reshape(V * 3, P).T).reshape(-1, V, 3)


def rigid_transforms(rot_mats: torch.Tensor, joints: torch.Tensor,
                     parents: tuple[int, ...]) -> tuple[torch.Tensor, torch.Tensor]:
    """Compose joint rotations along the kinematic tree.

    Args:
        rot_mats: (B, J, 3, 3) local rotations (joint 0 = global orientation).
        joints: (B, J, 3) rest-pose joint locations of the shaped model, metres.
        parents: (J,) parent indices, parents[0] = -1, each parent before its children.
    Returns:
        posed_joints: (B, J, 3) joint locations after posing.
        skinning: (B, J, 4, 4) transforms taking rest-pose points to posed points for each joint.
    """
    B, J = joints.shape[:2]
    rel_joints = joints.clone()
    rel_joints[:, 1:] = joints[:, 1:] - joints[:, list(parents[1:])]
    local = torch.cat([torch.cat([rot_mats, rel_joints[..., None]], dim=-1),
                       _homogeneous_row(joints).expand(B, J, 1, 4)], dim=-2)  # (B, J, 4, 4)
    # One batched product per tree level (3 for a hand) instead of one per joint: a fit spends its
    # time in per-operation overhead, forward and backward.
    world = local.clone()
    for level in _tree_levels(tuple(parents))[1:]:
        world[:, list(level)] = world[:, [parents[j] for j in level]] @ local[:, list(level)]
    posed_joints = world[..., :3, 3]
    # Remove each joint's rest location so the transform applies to rest-pose vertices directly.
    rest_in_world = torch.einsum("bjik,bjk->bji", world[..., :3, :3], joints)
    skinning = world.clone()
    skinning[..., :3, 3] = posed_joints - rest_in_world
    return posed_joints, skinning


def _homogeneous_row(like: torch.Tensor) -> torch.Tensor:
    return torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=like.dtype, device=like.device).reshape(1, 1, 1, 4)


@functools.lru_cache(maxsize=16)
def _tree_levels(parents: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    """Joints grouped by depth in the kinematic tree: ((root,), (children of root), ...)."""
    depth = [0] * len(parents)
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1
    return tuple(tuple(j for j in range(len(parents)) if depth[j] == d) for d in range(max(depth) + 1))


def skin_vertices(vertices: torch.Tensor, weights: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
    """Blend per-joint transforms: vertices (B, V, 3), weights (V, J), transforms (B, J, 4, 4) -> (B, V, 3).

    Written as one matmul plus elementwise products: a batched 3x3 product per vertex (einsum/bmm)
    was the slowest step of a fit on CPU (measured: most of the backward pass).
    """
    B, J = transforms.shape[:2]
    blended = (weights @ transforms[:, :, :3, :].reshape(B, J, 12)).reshape(B, -1, 3, 4)  # (B, V, 3, 4)
    return (blended[..., :3] * vertices[:, :, None, :]).sum(-1) + blended[..., 3]


def lbs(betas: torch.Tensor, full_pose: torch.Tensor, v_template: torch.Tensor, shapedirs: torch.Tensor,
        posedirs: torch.Tensor | None, J_regressor: torch.Tensor, parents: tuple[int, ...],
        weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
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
