"""The hand model's forward pass as the fit needs it: only the points the objective reads, few operations.

`HandLayer` poses every vertex and checks its inputs; a fit step needs far less: the 21 keypoints, the
vertices sampled for the silhouette term, the articulation and the joints' rotation matrices (for the
joint-limit prior). `FitKinematics` computes exactly those (tests check equality with `HandLayer`),
with the kinematic chain as three batched products, and their derivatives (`jacobian`) for the
Levenberg-Marquardt solver. No checks or in-place writes, so that tests can also differentiate it
with `torch.func`.

Parameter vector per frame (P = 16 + k): global rotation (3, axis-angle about the wrist joint),
translation (3, metres), k PCA pose coefficients, 10 betas.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from workers.geometry.rotation import axis_angle_to_matrix
from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.keypoints import FREIHAND_FROM_MANO, MANO_PARENTS, NUM_BETAS, NUM_JOINTS

# MANO's tree is the wrist plus five chains of three joints, numbered chain by chain: joints
# 1, 4, 7, 10, 13 are the chains' bases (children of the wrist); joint j + 1 is the child of joint j.
_CHAIN_BASES = (1, 4, 7, 10, 13)
NUM_POSE_FEATURES = 9 * (NUM_JOINTS - 1)


@dataclass
class FitGeometry:
    """What the objective reads for a batch of B frames (metres, world frame).

    Attributes:
        keypoints: (B, 21, 3) FreiHAND keypoints.
        silhouette_vertices: (B, Vs, 3) the vertices sampled for the silhouette term (None when not asked for).
        articulation: (B, 45) axis-angle articulation (mean pose included), radians.
        joint_rotations: (B, 15, 3, 3) local rotation matrices of the articulated joints 1..15.
    """

    keypoints: torch.Tensor
    silhouette_vertices: torch.Tensor | None
    articulation: torch.Tensor
    joint_rotations: torch.Tensor


@dataclass
class VertexSet:
    """Constant arrays of the vertices posed one by one (S of them).

    Attributes:
        template: (S, 3).  shape_dirs: (10, 3 S).  weights: (S, 16).  shape_dirs_3d: (S, 3, 10).
        pose_dirs: (135, 3 S) and pose_dirs_3d: (S, 3, 135), None without pose correctives.
    """

    template: torch.Tensor
    shape_dirs: torch.Tensor
    weights: torch.Tensor
    shape_dirs_3d: torch.Tensor
    pose_dirs: torch.Tensor | None
    pose_dirs_3d: torch.Tensor | None


@dataclass
class GeometryJacobian:
    """FitGeometry at params plus derivatives with respect to the A active parameter columns.

    Attributes:
        geometry: at params.
        d_keypoints: (B, 21, 3, A).  d_vertices: (B, Vs, 3, A) or None.
        rotation_probes: (B, 1 + A, 15, 3, 3) joint rotations at params and at params + step * e_a
            (for terms of the rotations, differentiated by forward differences).
        step: the forward-difference step.
    """

    geometry: FitGeometry
    d_keypoints: torch.Tensor
    d_vertices: torch.Tensor | None
    rotation_probes: torch.Tensor
    step: float


class FitKinematics:
    """Constant tensors of the hand model restricted to what a fit reads.

    Posed points are linear in the 16 skinning transforms A_j = [R_j | shift_j] (3 x 4): a vertex is
    sum_j w_ij A_j [v_i(beta); 1] and a regressed joint sum_k A_k [m_jk(beta); c_jk] (`points`). So the
    derivatives of every point need only the derivatives of the 16 transforms (a few hundred numbers,
    by forward differences of the small kinematic chain) and one matrix product (`jacobian`).

    Args:
        arrays: the hand model (its parents must be MANO's tree, which `validate` enforces).
        silhouette_ids: (Vs,) vertex ids sampled for the silhouette term.
        num_pca_comps: k, PCA components of the articulation; zero coefficients mean MANO's mean pose.
        dtype, device: of every tensor.
    """

    def __init__(self, arrays: HandModelArrays, silhouette_ids: np.ndarray, num_pca_comps: int,
                 dtype: torch.dtype, device: torch.device) -> None:
        arrays.validate()
        assert tuple(int(p) for p in arrays.parents) == MANO_PARENTS
        # Pose correctives (official MANO) add posedirs @ (R - I) to each rest vertex; the built-in hand has none.
        self.has_pose_correctives = bool(np.any(arrays.posedirs != 0))
        self.num_pca_comps = num_pca_comps
        self.num_params = 6 + num_pca_comps + NUM_BETAS
        self.dtype, self.device = dtype, device

        def tensor(value: np.ndarray, kind: torch.dtype = dtype) -> torch.Tensor:
            return torch.as_tensor(np.ascontiguousarray(value), dtype=kind, device=device)

        def vertex_set(ids: np.ndarray) -> VertexSet:
            ids = np.asarray(ids, dtype=np.int64)
            pose = arrays.posedirs[ids] if self.has_pose_correctives else None
            return VertexSet(tensor(arrays.v_template[ids]), tensor(arrays.shapedirs[ids].reshape(-1, NUM_BETAS).T),
                             tensor(arrays.weights[ids]), tensor(arrays.shapedirs[ids]),
                             None if pose is None else tensor(pose.reshape(-1, NUM_POSE_FEATURES).T),
                             None if pose is None else tensor(pose))

        # The fingertips (keypoints) are posed on their own, so a keypoint-only step poses 5 vertices.
        self.tips = vertex_set(arrays.fingertip_vertex_ids)
        self.silhouette = vertex_set(silhouette_ids)
        # Rest joints are linear in the betas: J(beta) = J_template + beta @ J_dirs.
        reg = arrays.J_regressor
        self.joint_template = tensor(reg @ arrays.v_template)  # (16, 3)
        self.joint_dirs = tensor(np.einsum("jv,vcs->sjc", reg, arrays.shapedirs).reshape(NUM_BETAS, NUM_JOINTS * 3))
        # Regressed joint j of the posed mesh = sum_k R_k m_jk + c_jk shift_k with c_jk = sum_i r_ji w_ik
        # and m_jk = sum_i r_ji w_ik v_i(beta), linear in beta: exact, and no regressor-support vertices.
        rw = reg[:, :, None] * arrays.weights[None]  # (16 joints, V, 16 bones)
        self.regressed_bone_weights = tensor(rw.sum(1))  # (16, 16)
        self.regressed_template = tensor(np.einsum("jvk,vc->jkc", rw, arrays.v_template))  # (16, 16, 3)
        self.regressed_dirs = tensor(np.einsum("jvk,vcs->sjkc", rw, arrays.shapedirs))  # (10, 16, 16, 3)
        self.regressed_pose_dirs = (tensor(np.einsum("jvk,vcp->pjkc", rw, arrays.posedirs))  # (135, 16, 16, 3)
                                    if self.has_pose_correctives else None)
        self.pca = tensor(arrays.hands_components[:num_pca_comps])  # (k, 45)
        self.pose_mean = tensor(arrays.hands_mean)  # (45,)
        self.keypoint_order = tensor(np.asarray(FREIHAND_FROM_MANO), torch.int64)
        self.bases = list(_CHAIN_BASES)

    def split(self, params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, P) -> global rotation (B, 3), translation (B, 3), coefficients (B, k), betas (B, 10)."""
        k = self.num_pca_comps
        return params[:, :3], params[:, 3:6], params[:, 6: 6 + k], params[:, 6 + k:]

    # -- forward -------------------------------------------------------------------------------------
    def transforms(self, params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The kinematic chain: params (B, P) -> skinning transforms (B, 16, 3, 4) (rest point -> posed
        point, before translation), local joint rotations (B, 15, 3, 3), articulation (B, 45)."""
        orient, _, coefficients, betas = self.split(params)
        B = params.shape[0]
        articulation = coefficients @ self.pca + self.pose_mean  # (B, 45)
        rot = axis_angle_to_matrix(torch.cat([orient, articulation], 1).reshape(B, NUM_JOINTS, 3))
        joints = self.joint_template + (betas @ self.joint_dirs).reshape(B, NUM_JOINTS, 3)  # (B, 16, 3) rest
        # The chain, level by level: each level's five joints in one batched product.
        world_R, world_t = [rot[:, 0]], [joints[:, 0]]
        R_parent = rot[:, :1].expand(B, 5, 3, 3)
        t_parent = joints[:, :1].expand(B, 5, 3)
        for level in range(3):
            ids = [b + level for b in self.bases]
            parents = [b + level - 1 for b in self.bases] if level else [0] * 5
            offset = joints[:, ids] - joints[:, parents]  # (B, 5, 3) bone in the rest pose
            t_parent = (R_parent @ offset[..., None])[..., 0] + t_parent
            R_parent = R_parent @ rot[:, ids]
            world_R.append(R_parent)
            world_t.append(t_parent)
        # Reorder (wrist, level 1 x 5, level 2 x 5, level 3 x 5) into MANO's chain-by-chain numbering.
        R_chain = torch.stack(world_R[1:], 2).reshape(B, 15, 3, 3)
        t_chain = torch.stack(world_t[1:], 2).reshape(B, 15, 3)
        R_world = torch.cat([world_R[0][:, None], R_chain], 1)  # (B, 16, 3, 3)
        t_world = torch.cat([world_t[0][:, None], t_chain], 1)  # (B, 16, 3) posed joints
        # Skinning transforms take rest points to posed points: x -> R_w x + (t_w - R_w J_rest).
        shift = t_world - (R_world @ joints[..., None])[..., 0]
        return torch.cat([R_world, shift[..., None]], -1), rot[:, 1:], articulation

    @staticmethod
    def pose_features(rotations: torch.Tensor) -> torch.Tensor:
        """MANO's pose-corrective input: local rotations (B, 15, 3, 3) -> (B, 135), R - I flattened."""
        eye = torch.eye(3, dtype=rotations.dtype, device=rotations.device)
        return (rotations - eye).flatten(1)

    def _vertex_factors(self, vertex_set: VertexSet, betas: torch.Tensor,
                        features: torch.Tensor | None) -> torch.Tensor:
        """(B, S, 64): w_ij [v_i(beta, pose); 1]_c at (j, c), so that posed = factors @ vec(A)."""
        B = betas.shape[0]
        shaped = vertex_set.template + (betas @ vertex_set.shape_dirs).reshape(B, -1, 3)  # (B, S, 3)
        if features is not None and vertex_set.pose_dirs is not None:
            shaped = shaped + (features @ vertex_set.pose_dirs).reshape(B, -1, 3)
        homogeneous = torch.cat([shaped, torch.ones_like(shaped[..., :1])], -1)  # (B, S, 4)
        return (vertex_set.weights[None, :, :, None] * homogeneous[:, :, None, :]).reshape(B, -1, NUM_JOINTS * 4)

    def _regressed_factors(self, betas: torch.Tensor, features: torch.Tensor | None) -> torch.Tensor:
        """(B, 16, 64): [m_jk(beta, pose); c_jk] at (k, c), so that regressed joints = factors @ vec(A)."""
        B = betas.shape[0]
        m = self.regressed_template + torch.einsum("bs,sjkc->bjkc", betas, self.regressed_dirs)  # (B, 16, 16, 3)
        if features is not None and self.regressed_pose_dirs is not None:
            m = m + torch.einsum("bp,pjkc->bjkc", features, self.regressed_pose_dirs)
        c = self.regressed_bone_weights.expand(B, NUM_JOINTS, NUM_JOINTS)[..., None]
        return torch.cat([m, c], -1).reshape(B, NUM_JOINTS, NUM_JOINTS * 4)

    @staticmethod
    def _vec(transforms: torch.Tensor) -> torch.Tensor:
        """(..., 16, 3, 4) -> (..., 64, 3): row (j, c) holds column c of A_j."""
        return transforms.transpose(-1, -2).reshape(*transforms.shape[:-3], NUM_JOINTS * 4, 3)

    def points(self, params: torch.Tensor, transforms: torch.Tensor, rotations: torch.Tensor,
               with_vertices: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Keypoints (B, 21, 3) and silhouette vertices (B, Vs, 3) (or None) for given transforms and
        local joint rotations (B, 15, 3, 3) (these only matter for pose correctives)."""
        _, transl, _, betas = self.split(params)
        features = self.pose_features(rotations) if self.has_pose_correctives else None
        vec = self._vec(transforms)  # (B, 64, 3)
        regressed = self._regressed_factors(betas, features) @ vec
        tips = self._vertex_factors(self.tips, betas, features) @ vec
        keypoints = torch.cat([regressed, tips], 1)[:, self.keypoint_order] + transl[:, None]
        vertices = None
        if with_vertices:
            vertices = self._vertex_factors(self.silhouette, betas, features) @ vec + transl[:, None]
        return keypoints, vertices

    def __call__(self, params: torch.Tensor, with_vertices: bool = True) -> FitGeometry:
        """Pose and shape the hand: params (B, P) -> FitGeometry. Same results as `HandLayer`."""
        transforms, rotations, articulation = self.transforms(params)
        keypoints, vertices = self.points(params, transforms, rotations, with_vertices)
        return FitGeometry(keypoints, vertices, articulation, rotations)

    # -- derivatives ---------------------------------------------------------------------------------
    def jacobian(self, params: torch.Tensor, active: torch.Tensor, with_vertices: bool = True,
                 step: float = 1e-6) -> GeometryJacobian:
        """FitGeometry and its derivatives with respect to the `active` (A,) columns of params (B, P).

        The transforms are differentiated by forward differences (one batched pass of the chain with
        each active column nudged by `step`; use float64), the points then exactly: through the
        transforms by one product, through the betas' shape directions and through the translation
        in closed form.
        """
        B, P = params.shape
        A = len(active)
        probe = params[:, None].repeat(1, 1 + A, 1)  # (B, 1 + A, P): params, then one column nudged each
        probe[:, 1 + torch.arange(A, device=params.device), active] += step
        transforms, rotations, articulation = self.transforms(probe.reshape(B * (1 + A), P))
        transforms = transforms.reshape(B, 1 + A, NUM_JOINTS, 3, 4)
        base = transforms[:, 0]
        d_vec = self._vec((transforms[:, 1:] - transforms[:, :1]) / step)  # (B, A, 64, 3)
        d_vec = d_vec.permute(0, 2, 3, 1).reshape(B, NUM_JOINTS * 4, 3 * A)
        rotations = rotations.reshape(B, 1 + A, 15, 3, 3)
        keypoints, vertices = self.points(params, base, rotations[:, 0], with_vertices)
        _, _, _, betas = self.split(params)
        features = d_features = None
        if self.has_pose_correctives:
            all_features = self.pose_features(rotations.reshape(-1, 15, 3, 3)).reshape(B, 1 + A, -1)
            features = all_features[:, 0]
            d_features = ((all_features[:, 1:] - all_features[:, :1]) / step).transpose(1, 2)  # (B, 135, A)
        k = self.num_pca_comps
        beta_cols = torch.nonzero(active >= 6 + k)[:, 0]  # positions in `active` of betas
        transl_cols = torch.nonzero((active >= 3) & (active < 6))[:, 0]
        R_world = base[..., :3]  # (B, 16, 3, 3)

        def chain(factors: torch.Tensor, shape_term: torch.Tensor, pose_term: torch.Tensor | None) -> torch.Tensor:
            d = (factors @ d_vec).reshape(B, -1, 3, A)
            if len(beta_cols):
                d = d.index_add(3, beta_cols, shape_term[..., active[beta_cols] - (6 + k)])
            if len(transl_cols):
                eye = torch.eye(3, dtype=d.dtype, device=d.device)[:, active[transl_cols] - 3]  # (3, T)
                d = d.index_add(3, transl_cols, eye.expand(*d.shape[:2], 3, len(transl_cols)))
            return d if pose_term is None else d + pose_term

        # Shape (and pose-corrective) directions move each vertex before skinning:
        # d posed_i / d beta = (sum_j w_ij R_j) S_i, and likewise through the pose features.
        def vertex_terms(vertex_set: VertexSet) -> tuple[torch.Tensor, torch.Tensor | None]:
            blend = (vertex_set.weights @ R_world.reshape(B, NUM_JOINTS, 9)).reshape(B, -1, 3, 3)
            shape_term = blend @ vertex_set.shape_dirs_3d  # (B, S, 3, 10)
            pose_term = None
            if d_features is not None:
                pose_term = blend @ torch.einsum("scp,bpa->bsca", vertex_set.pose_dirs_3d, d_features)
            return shape_term, pose_term

        regressed_beta = torch.einsum("bkrc,qjkc->bjrq", R_world, self.regressed_dirs)  # (B, 16, 3, 10)
        regressed_pose = None
        if d_features is not None:
            moved = torch.einsum("pjkc,bpa->bjkca", self.regressed_pose_dirs, d_features)
            regressed_pose = torch.einsum("bkrc,bjkca->bjra", R_world, moved)  # (B, 16, 3, A)
        d_regressed = chain(self._regressed_factors(betas, features), regressed_beta, regressed_pose)
        d_tips = chain(self._vertex_factors(self.tips, betas, features), *vertex_terms(self.tips))
        d_keypoints = torch.cat([d_regressed, d_tips], 1)[:, self.keypoint_order]
        d_vertices = None
        if with_vertices:
            d_vertices = chain(self._vertex_factors(self.silhouette, betas, features), *vertex_terms(self.silhouette))
        geometry = FitGeometry(keypoints, vertices, articulation.reshape(B, 1 + A, -1)[:, 0], rotations[:, 0])
        return GeometryJacobian(geometry, d_keypoints, d_vertices, rotations, step)
