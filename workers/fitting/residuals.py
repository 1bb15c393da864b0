"""The fitting objective (paper eq. 1-6) as a vector of residuals whose squares sum to it.

L = w2D L2D + w3D L3D + wseg Lseg + wshape Lshape + wpose Lpose + wnn Lnn + wlim Llimits is the same
objective as the pure loss functions of `losses.py` (a test checks the values agree term by term),
written as r(theta) with sum(r^2) = L so that a Gauss-Newton / Levenberg-Marquardt solver can use
its Jacobian. Robust penalties rho(|d|^2) become d * sqrt(rho(|d|^2)) / |d|. The two discrete choices
of the objective (the model vertex nearest to each mask boundary sample, the N bank poses nearest to
the articulation) are made by `Objective.associate` at the current parameters and held fixed while
a Jacobian is taken, as in ICP; the objective's value always uses fresh associations.

Shapes: B frames, C views, K = 21 keypoints, Vs silhouette vertices, N boundary samples, P params.
`Objective.residuals` is written for `torch.func` (no data-dependent control flow, no in-place
writes): tests take its Jacobian by autodiff to check `gauss_newton.normal_equations`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from workers.fitting.config import FitConfig
from workers.fitting.differential import RigProjector, image_corners
from workers.fitting.kinematics import FitGeometry, FitKinematics
from workers.handmodel.limits import JointFrames

# Without a 3D weight (the first round) given 3D points still help placement in the first stage.
COARSE_STAGE_KP3D_WEIGHT = 100.0


@dataclass
class Targets:
    """Constant inputs of one batch's objective.

    Attributes:
        clicks: (B, C, K, 2) pixels (0 where not clicked); click_weights: (B, C, K).
        keypoints_3d: (B, K, 3) metres; keypoint_3d_weights: (B, K).
        outside: (F, C, H * W) distance to the mask per pixel, view pixels (flattened images).
        outside_rows: (B,) long, the row of `outside` each frame reads (several starts of one frame share
            its images); None: row b for frame b.
        height, width: of the padded distance images.
        boundary: (B, C, N, 2) mask boundary samples, pixels; boundary_weights: (B, C, N), 1 valid, 0 padding.
        boundary_normals: (B, C, N, 2) the mask's outward unit normal at each boundary sample.
        view_weights: (B, C) 1 where the view has a mask.
        outside_cap, coverage_cap: (B,) robust scales (reference pixels) of the two silhouette terms, per
            frame (they depend on the kind of mask, see FitConfig).
    """

    clicks: torch.Tensor
    click_weights: torch.Tensor
    keypoints_3d: torch.Tensor
    keypoint_3d_weights: torch.Tensor
    outside: torch.Tensor | None = None
    height: int = 0
    width: int = 0
    boundary: torch.Tensor | None = None
    boundary_weights: torch.Tensor | None = None
    view_weights: torch.Tensor | None = None
    boundary_normals: torch.Tensor | None = None
    outside_rows: torch.Tensor | None = None
    outside_cap: torch.Tensor | None = None
    coverage_cap: torch.Tensor | None = None

    def repeat(self, times: int) -> Targets:
        """Each frame's targets `times` times in a row (for several starts per frame)."""
        def rep(t: torch.Tensor | None) -> torch.Tensor | None:
            return t.repeat_interleave(times, 0) if t is not None and times > 1 else t

        rows = None
        if self.outside is not None:  # the distance images are shared, not copied
            rows = self.outside_rows
            rows = torch.arange(len(self.clicks), device=self.clicks.device) if rows is None else rows
            rows = rows.repeat_interleave(times)
        return Targets(rep(self.clicks), rep(self.click_weights), rep(self.keypoints_3d), rep(self.keypoint_3d_weights),
                       self.outside, self.height, self.width, rep(self.boundary), rep(self.boundary_weights),
                       rep(self.view_weights), rep(self.boundary_normals), rows, rep(self.outside_cap),
                       rep(self.coverage_cap))

    def to(self, dtype: torch.dtype) -> Targets:
        """The same targets with every float tensor in `dtype`."""
        def cast(t: torch.Tensor | None) -> torch.Tensor | None:
            return t.to(dtype) if t is not None else None

        return Targets(cast(self.clicks), cast(self.click_weights), cast(self.keypoints_3d),
                       cast(self.keypoint_3d_weights), cast(self.outside), self.height, self.width,
                       cast(self.boundary), cast(self.boundary_weights), cast(self.view_weights),
                       cast(self.boundary_normals), self.outside_rows, cast(self.outside_cap),
                       cast(self.coverage_cap))


@dataclass
class Associations:
    """Discrete choices at the current parameters: nearest silhouette vertex of each boundary sample
    (B, C, N) and the nearest bank poses (B, n)."""

    boundary_vertex: torch.Tensor | None
    bank_poses: torch.Tensor

    def where(self, take: torch.Tensor, other: Associations) -> Associations:
        """Per frame: self where take (B,) bool, else other."""
        def pick(a: torch.Tensor | None, b: torch.Tensor | None) -> torch.Tensor | None:
            if a is None or b is None:
                return None
            return torch.where(take.reshape(-1, *([1] * (a.dim() - 1))), a, b)

        return Associations(pick(self.boundary_vertex, other.boundary_vertex), pick(self.bank_poses, other.bank_poses))


def robust_residual(diff: torch.Tensor, scale: float | torch.Tensor, kind: str) -> torch.Tensor:
    """diff (..., D) -> (..., D) residual vectors e with |e|^2 = robust_penalty(|diff|^2) of `losses.py`;
    scale a number or a tensor broadcasting against diff."""
    if kind == "none":
        return diff
    squared = (diff * diff).sum(-1, keepdim=True)
    if kind == "geman_mcclure":
        return diff * (scale / torch.sqrt(scale * scale + squared))
    if kind == "huber":
        r = squared.clamp_min(1e-12).sqrt()
        above = torch.sqrt((2 * scale * r - scale * scale).clamp_min(0)) / r
        factor = torch.where(r < scale, torch.ones_like(r), above)
        return diff * factor
    raise ValueError(f"unknown robust penalty {kind!r}")


def bilinear_lookup(images: torch.Tensor, height: int, width: int, points_px: torch.Tensor,
                    rows: torch.Tensor | None = None) -> torch.Tensor:
    """images (F, C, H * W) flattened, points_px (B, C, N, 2) as (x, y) -> (B, C, N); frame b reads
    image row rows[b] (None: row b).

    The same values and derivatives as `losses.sample_image` (grid_sample, bilinear, border padding,
    pixel centres at integers) written with gathers, which forward-mode autodiff supports.
    """
    x = points_px[..., 0].clamp(0, width - 1)
    y = points_px[..., 1].clamp(0, height - 1)
    x0 = x.detach().floor().clamp(max=max(width - 2, 0))
    y0 = y.detach().floor().clamp(max=max(height - 2, 0))
    fx, fy = x - x0, y - y0
    v = image_corners(images, height, width, x0, y0, rows)
    return ((1 - fx) * (1 - fy) * v[..., 0] + fx * (1 - fy) * v[..., 1]
            + (1 - fx) * fy * v[..., 2] + fx * fy * v[..., 3])


class Objective:
    """The objective of one fit: residual blocks, their associations and the per-term values.

    Args:
        kinematics: the reduced hand model.
        cameras: `stack_cameras` tensors (K, dist, R, t).
        px_scale: (C,) view pixels -> reference pixels.
        pose_bank: (M, 45) articulations of the nearest-pose prior.
        limit_frames: anatomical joint frames and limits.
        config: weights, robust penalties and caps.
    """

    def __init__(self, kinematics: FitKinematics, cameras: dict[str, torch.Tensor], px_scale: torch.Tensor,
                 pose_bank: torch.Tensor, limit_frames: JointFrames, config: FitConfig) -> None:
        self.kin = kinematics
        self.projector = RigProjector(**cameras)
        self.px_scale = px_scale
        self.bank = pose_bank
        self.config = config
        self.limit_axes = limit_frames.torch_axes(pose_bank)  # (15, 3, 3)
        self.limit_lower, self.limit_upper = (t.reshape(1, -1) for t in limit_frames.torch_limits(pose_bank))

    # -- pieces shared with gauss_newton ---------------------------------------------------------------
    def uses_vertices(self, targets: Targets, silhouette: bool, coarse: bool) -> bool:
        """Whether the objective reads the silhouette (the first stage and mask-less fits do not)."""
        return silhouette and not coarse and targets.outside is not None

    def kp3d_weight(self, coarse: bool) -> float:
        w = self.config.weights.kp3d
        if w > 0:
            return w
        return COARSE_STAGE_KP3D_WEIGHT if coarse else 0.0

    def boundary_frame(self, targets: Targets) -> torch.Tensor:
        """(B, C, N, 2, 2): rows n and alpha t of each boundary sample (outward normal, tangent)."""
        n = targets.boundary_normals
        t = torch.stack([-n[..., 1], n[..., 0]], -1)
        return torch.stack([n, self.config.coverage_tangent_weight * t], -2)

    def limit_excess(self, rotations: torch.Tensor) -> torch.Tensor:
        """(B, 15, 3, 3) local joint rotations -> (B, 45) excess over the anatomical limits, radians
        (`limits.joint_limit_penalty` is the sum of its squares)."""
        axes = self.limit_axes
        L = axes.transpose(-1, -2) @ rotations @ axes  # local rotation in (flex, abduct, twist) coordinates
        abd = torch.asin(L[..., 0, 2].clamp(-1 + 1e-7, 1 - 1e-7))
        flex = torch.atan2(-L[..., 1, 2], L[..., 2, 2])
        twist = torch.atan2(-L[..., 0, 1], L[..., 0, 0])
        angles = torch.stack([flex, abd, twist], -1).reshape(rotations.shape[0], -1)
        return torch.relu(self.limit_lower - angles) + torch.relu(angles - self.limit_upper)

    def project(self, geo: FitGeometry) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Pixels of the keypoints (B, C, 21, 2) and silhouette vertices (B, C, Vs, 2) (or None), one pass."""
        if geo.silhouette_vertices is None:
            return self.projector.project(geo.keypoints), None
        pixels = self.projector.project(torch.cat([geo.keypoints, geo.silhouette_vertices], 1))
        K = geo.keypoints.shape[1]
        return pixels[:, :, :K], pixels[:, :, K:]

    # -- associations ----------------------------------------------------------------------------------
    @torch.no_grad()
    def associate(self, params: torch.Tensor, targets: Targets, silhouette: bool, coarse: bool = False) -> Associations:
        """The objective's discrete choices at params."""
        geo = self.kin(params, self.uses_vertices(targets, silhouette, coarse))
        return self._associate(geo, self.project(geo)[1], targets)

    def _associate(self, geo: FitGeometry, verts_px: torch.Tensor | None, targets: Targets) -> Associations:
        bank_d2 = torch.cdist(geo.articulation, self.bank).square()
        bank = bank_d2.topk(min(self.config.nn_neighbours, self.bank.shape[0]), dim=-1, largest=False).indices
        nearest = None
        if verts_px is not None and targets.boundary is not None:
            # Nearest in the coverage metric |F (v - b)|^2, F = rows (n, alpha t) (normal, tangent): a quadratic
            # form in v, so one matmul of per-sample coefficients with per-vertex monomials (the per-sample
            # constant b^T F^T F b does not change the choice). Centred on the view's samples, float32 is
            # ample for a choice (and 4x faster); min().indices is faster than argmin on CPU.
            centre = targets.boundary.mean(2, keepdim=True)  # (B, C, 1, 2)
            b = targets.boundary - centre
            v = verts_px - centre
            frame = self.boundary_frame(targets)  # (B, C, N, 2, 2)
            M = frame.transpose(-1, -2) @ frame  # (B, C, N, 2, 2)
            Mb = (M @ b[..., None])[..., 0]  # (B, C, N, 2)
            coefficients = torch.stack([M[..., 0, 0], 2 * M[..., 0, 1], M[..., 1, 1],
                                        -2 * Mb[..., 0], -2 * Mb[..., 1]], -1)
            x, y = v[..., 0], v[..., 1]
            monomials = torch.stack([x * x, x * y, y * y, x, y], -2)  # (B, C, 5, Vs)
            nearest = (coefficients.float() @ monomials.float()).min(-1).indices
        return Associations(nearest, bank)

    # -- value -----------------------------------------------------------------------------------------
    @torch.no_grad()
    def evaluate(self, params: torch.Tensor, targets: Targets, silhouette: bool,
                 coarse: bool = False) -> tuple[torch.Tensor, Associations]:
        """The objective L (B,) at params and the associations there (one pass of the hand model)."""
        geo = self.kin(params, self.uses_vertices(targets, silhouette, coarse))
        kp_px, verts_px = self.project(geo)
        assoc = self._associate(geo, verts_px, targets)
        blocks = self._blocks(geo, kp_px, verts_px, params, targets, assoc, coarse)
        return torch.cat(list(blocks.values()), 1).square().sum(1), assoc

    def terms(self, params: torch.Tensor, targets: Targets, silhouette: bool,
              coarse: bool = False) -> dict[str, torch.Tensor]:
        """Value of each weighted term (B,) at params (fresh associations): L is their sum."""
        with torch.no_grad():
            assoc = self.associate(params, targets, silhouette, coarse)
            blocks = self.residuals(params, targets, assoc, silhouette, coarse)
        return {name: (r * r).sum(1) for name, r in blocks.items()}

    # -- residuals -------------------------------------------------------------------------------------
    def residuals(self, params: torch.Tensor, targets: Targets, assoc: Associations, silhouette: bool,
                  coarse: bool = False) -> dict[str, torch.Tensor]:
        """Residual blocks name -> (B, R_name); sum over a block of r^2 is that weighted term."""
        geo = self.kin(params, self.uses_vertices(targets, silhouette, coarse))
        kp_px, verts_px = self.project(geo)
        return self._blocks(geo, kp_px, verts_px, params, targets, assoc, coarse)

    def stacked(self, params: torch.Tensor, targets: Targets, assoc: Associations, silhouette: bool,
                coarse: bool = False) -> torch.Tensor:
        """All residuals (B, R) of `residuals`, concatenated."""
        return torch.cat(list(self.residuals(params, targets, assoc, silhouette, coarse).values()), 1)

    def _blocks(self, geo: FitGeometry, kp_px: torch.Tensor, verts_px: torch.Tensor | None, params: torch.Tensor,
                targets: Targets, assoc: Associations, coarse: bool) -> dict[str, torch.Tensor]:
        cfg, w = self.config, self.config.weights
        B = params.shape[0]
        _, _, coefficients, betas = self.kin.split(params)
        blocks: dict[str, torch.Tensor] = {}

        # eq. 2: robust click residuals, a weighted mean over clicks.
        diff = (kp_px - targets.clicks) * self.px_scale[None, :, None, None]
        cw = targets.click_weights
        share = w.kp2d * cw / cw.sum((1, 2), keepdim=True).clamp_min(1e-9)
        e = robust_residual(diff, cfg.robust_scale_px, cfg.robust) * share[..., None].sqrt()
        blocks["kp2d"] = e.reshape(B, -1)

        # eq. 3: 3D keypoints in centimetres, a weighted mean.
        w3 = self.kp3d_weight(coarse)
        if w3 > 0:
            kw = targets.keypoint_3d_weights
            share3 = w3 * kw / kw.sum(1, keepdim=True).clamp_min(1e-9)
            blocks["kp3d"] = (100.0 * (geo.keypoints - targets.keypoints_3d) * share3[..., None].sqrt()).reshape(B, -1)

        # eq. 4: model outside the mask (EDT) and mask not covered by the model, summed over views.
        if verts_px is not None and targets.outside is not None:
            blocks["seg"] = self._silhouette(verts_px, targets, assoc)

        # eq. 5 and 6: shape and pose priors, nearest bank poses, joint limits.
        blocks["shape"] = (w.shape ** 0.5) * betas
        blocks["pose"] = (w.pose ** 0.5) * coefficients
        n = assoc.bank_poses.shape[1]
        near = self.bank[assoc.bank_poses]  # (B, n, 45)
        blocks["nn"] = ((w.nn / n) ** 0.5 * (geo.articulation[:, None] - near)).reshape(B, -1)
        blocks["limits"] = (w.limits ** 0.5) * self.limit_excess(geo.joint_rotations)
        return blocks

    def _silhouette(self, verts_px: torch.Tensor, targets: Targets, assoc: Associations) -> torch.Tensor:
        w = self.config.weights
        B, _, Vs, _ = verts_px.shape
        views = targets.view_weights  # (B, C)
        scale = self.px_scale[None, :, None]
        # Model outside the mask: the distance field at each projected vertex, mean over vertices.
        dist = bilinear_lookup(targets.outside, targets.height, targets.width, verts_px,
                               targets.outside_rows) * scale  # (B, C, Vs)
        cap = targets.outside_cap[:, None, None]
        outside = dist * (cap / torch.sqrt(cap * cap + dist * dist)) * (w.seg * views[..., None] / Vs).sqrt()
        # Mask not covered: each boundary sample to its nearest projected vertex, mean over samples,
        # in the boundary's frame (along the normal, and alpha times along the tangent).
        idx = assoc.boundary_vertex  # (B, C, N)
        nearest = torch.gather(verts_px, 2, idx[..., None].expand(*idx.shape, 2))  # (B, C, N, 2)
        d = (self.boundary_frame(targets) @ ((nearest - targets.boundary) * scale[..., None])[..., None])[..., 0]
        bw = targets.boundary_weights
        share = w.seg * views[..., None] * bw / bw.sum(-1, keepdim=True).clamp_min(1e-9)
        cover = robust_residual(d, targets.coverage_cap[:, None, None, None], "geman_mcclure") * share[..., None].sqrt()
        return torch.cat([outside.reshape(B, -1), cover.reshape(B, -1)], 1)
