"""A batched torch layer for any MANO-compatible hand model (official MANO or the built-in hand)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.keypoints import FREIHAND_FROM_MANO, NUM_BETAS, NUM_POSE
from workers.handmodel.lbs import keypoints_from_vertices, lbs
from workers.handmodel.params import HandParams


@dataclass
class HandOutput:
    """Result of `HandLayer.forward`, metres, world frame (after global rotation and translation).

    Attributes:
        vertices: (B, V, 3) mesh vertices.
        joints: (B, 16, 3) skeleton joints in MANO order (the posed kinematic tree).
        keypoints: (B, 21, 3) FreiHAND keypoints: joints regressed from the posed vertices plus the
            fingertip vertices, in FreiHAND order.
        full_pose: (B, 48) axis-angle actually applied (global orientation + articulation), radians.
    """

    vertices: torch.Tensor
    joints: torch.Tensor
    keypoints: torch.Tensor
    full_pose: torch.Tensor


class HandLayer(nn.Module):
    """theta = (betas 10, articulation 45 axis-angle or k PCA coefficients, global_orient 3, transl 3).

    Args:
        arrays: the model's arrays (see `workers.handmodel.load_hand_model`).
        use_pca: if True, `pose` holds `num_pca_comps` PCA coefficients instead of 45 axis-angle values.
        num_pca_comps: number of PCA components used (1..45).
        flat_hand_mean: if True, zero articulation is the flat template hand; if False, MANO's mean
            pose `hands_mean` is added (MANO's own default).
        dtype: float32 or float64 buffers and outputs.
    """

    def __init__(self, arrays: HandModelArrays, *, use_pca: bool = False, num_pca_comps: int = 45,
                 flat_hand_mean: bool = True, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        if not 1 <= num_pca_comps <= NUM_POSE:
            raise ValueError(f"num_pca_comps must be in 1..{NUM_POSE}, got {num_pca_comps}")
        if dtype not in (torch.float32, torch.float64):
            raise ValueError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        arrays.validate()
        self.arrays = arrays
        self.use_pca = use_pca
        self.num_pca_comps = num_pca_comps
        self.flat_hand_mean = flat_hand_mean
        self.parents = tuple(int(p) for p in arrays.parents)
        # The built-in hand has no pose correctives: skipping them saves a third of a fit's time.
        self.has_pose_correctives = bool(np.any(arrays.posedirs != 0))

        def buffer(name: str, value: np.ndarray, kind: torch.dtype = dtype) -> None:
            self.register_buffer(name, torch.as_tensor(np.ascontiguousarray(value), dtype=kind), persistent=False)

        buffer("v_template", arrays.v_template)
        buffer("shapedirs", arrays.shapedirs)
        buffer("posedirs", arrays.posedirs)
        buffer("J_regressor", arrays.J_regressor)
        buffer("weights", arrays.weights)
        buffer("faces", arrays.faces, torch.int64)
        buffer("pca_components", arrays.hands_components[:num_pca_comps])
        mean = np.zeros(NUM_POSE) if flat_hand_mean else arrays.hands_mean
        buffer("pose_mean", mean)
        buffer("tip_ids", arrays.fingertip_vertex_ids, torch.int64)
        buffer("keypoint_order", np.asarray(FREIHAND_FROM_MANO), torch.int64)

    @property
    def num_vertices(self) -> int:
        return self.arrays.num_vertices

    @property
    def pose_dim(self) -> int:
        return self.num_pca_comps if self.use_pca else NUM_POSE

    def articulation(self, pose: torch.Tensor) -> torch.Tensor:
        """Axis-angle articulation (B, 45) for `pose` (B, pose_dim), mean pose included."""
        hand_pose = pose @ self.pca_components if self.use_pca else pose
        return hand_pose + self.pose_mean

    def forward(self, betas: torch.Tensor | None = None, pose: torch.Tensor | None = None,
                global_orient: torch.Tensor | None = None, transl: torch.Tensor | None = None,
                batch_size: int | None = None) -> HandOutput:
        """Pose and shape the hand.

        Args:
            betas: (B, 10) shape coefficients (zeros if None).
            pose: (B, 45) axis-angle radians, or (B, k) PCA coefficients with use_pca (zeros if None).
            global_orient: (B, 3) axis-angle of the root about the wrist joint, radians (zeros if None).
            transl: (B, 3) translation, metres (zeros if None).
            batch_size: B when every input is None.
        Returns:
            HandOutput with vertices (B, V, 3), joints (B, 16, 3), keypoints (B, 21, 3).
        """
        given = [t for t in (betas, pose, global_orient, transl) if t is not None]
        B = given[0].shape[0] if given else (batch_size or 1)
        kw = {"dtype": self.v_template.dtype, "device": self.v_template.device}
        betas = _check("betas", betas, (B, NUM_BETAS), kw)
        pose = _check("pose", pose, (B, self.pose_dim), kw)
        global_orient = _check("global_orient", global_orient, (B, 3), kw)
        transl = _check("transl", transl, (B, 3), kw)

        full_pose = torch.cat([global_orient, self.articulation(pose)], dim=1)  # (B, 48)
        posedirs = self.posedirs if self.has_pose_correctives else None
        vertices, joints = lbs(betas, full_pose, self.v_template, self.shapedirs, posedirs,
                               self.J_regressor, self.parents, self.weights)
        keypoints = keypoints_from_vertices(vertices, self.J_regressor, self.tip_ids, self.keypoint_order)
        offset = transl[:, None, :]
        return HandOutput(vertices + offset, joints + offset, keypoints + offset, full_pose)

    def pose_params(self, params: HandParams) -> HandOutput:
        """Pose and shape from `HandParams` with a batch axis (fields (B, 10), (B, 45), (B, 3), (B, 3); build
        them with `HandParams.from_theta(theta (B, 61))`). Needs use_pca=False (theta holds axis-angle)."""
        if self.use_pca:
            raise ValueError("pose_params takes axis-angle articulation: build the layer with use_pca=False")
        if params.betas.ndim != 2:
            raise ValueError(f"pose_params needs a batch axis: betas (B, 10), got {params.betas.shape}")
        return self(params.betas, params.pose, params.global_orient, params.transl)


def _check(name: str, value: torch.Tensor | None, shape: tuple[int, int], kw: dict) -> torch.Tensor:
    """Default to zeros; otherwise check the shape and finiteness and cast to the layer's dtype."""
    if value is None:
        return torch.zeros(shape, **kw)
    value = torch.as_tensor(value).to(**kw)
    if tuple(value.shape) != shape:
        raise ValueError(f"{name} must have shape {shape}, got {tuple(value.shape)}")
    if not torch.isfinite(value).all():
        raise ValueError(f"{name} contains non-finite values")
    return value
