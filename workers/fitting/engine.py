"""The fitting engine: multi-view clicks, 3D keypoints and silhouettes -> hand pose and shape.

Minimises L = L2D_kp + L3D_kp + L_seg + L_shape + L_pose (+ joint limits), the paper's objective
(section "Hand Model Fitting with Sparse Annotations", eq. 1-6), over a batch of frames at once (each
frame keeps its own parameters, so frames stay independent). Two stages: global pose and
articulation from keypoints, then everything with silhouettes against wrist-cut masks.

The default optimiser is batched Levenberg-Marquardt on the objective's residual form
(`residuals.py`, `gauss_newton.py`, `solver.py`): tens of steps instead of the hundreds Adam needs,
which makes a fit interactive on two CPU cores, and several starts per frame against the fit's local
minima. The paper's Adam is kept (`FitConfig.adam()`), on the same objective (`losses.py`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import partial

import numpy as np
import torch

from workers.fitting import losses
from workers.fitting.config import FitConfig
from workers.fitting.frame_masks import PreparedMasks, prepare_masks
from workers.fitting.gauss_newton import normal_equations
from workers.fitting.init import Placement, observed_points_3d, rank_placements
from workers.fitting.inputs import FitInputError, FrameObservations
from workers.fitting.kinematics import FitKinematics
from workers.fitting.masks import boundary_samples, cut_forearm
from workers.fitting.residuals import Objective, Targets
from workers.fitting.result import FitDiagnostics, FitResult
from workers.fitting.solver import LMSettings, levenberg_marquardt
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points_torch, stack_cameras
from workers.handmodel import limits, pose_sampler
from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.layer import HandLayer
from workers.rendering import model_mask

log = logging.getLogger(__name__)

ProgressCallback = Callable[[float, str], None]


def farthest_point_ids(points: np.ndarray, count: int) -> np.ndarray:
    """Deterministic farthest-point sampling: (N, 3) -> (min(count, N),) indices spread over the surface."""
    count = min(count, len(points))
    chosen = np.zeros(count, dtype=np.int64)
    dist = np.full(len(points), np.inf)
    for i in range(1, count):
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i - 1]], axis=1))
        chosen[i] = int(np.argmax(dist))
    return chosen


class FittingEngine:
    """Fits a hand model to observations from one calibrated rig.

    Args:
        arrays: the hand model (MANO or the built-in stand-in).
        cameras: the C calibrated views every frame is seen from.
        config: weights and schedule.
        device, dtype: where and in what precision to optimise.
        pose_bank: (N, 45) articulations for the nearest-neighbour prior (default: the pose sampler's).
        init_poses: (M, 45) candidate articulations for initialisation (default: canonical poses).
    """

    def __init__(self, arrays: HandModelArrays, cameras: list[Camera], config: FitConfig | None = None, *,
                 device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32,
                 pose_bank: np.ndarray | None = None, init_poses: np.ndarray | None = None) -> None:
        self.arrays = arrays
        self.cameras = list(cameras)
        self.config = config or FitConfig()
        self.device = torch.device(device)
        self.dtype = dtype
        k = self.config.num_pca_comps
        # flat_hand_mean=False: zero PCA coefficients mean MANO's mean pose, where the PCA prior pulls.
        self.layer = HandLayer(arrays, use_pca=True, num_pca_comps=k, flat_hand_mean=False, dtype=dtype).to(device)
        self.cam = stack_cameras(self.cameras, dtype, self.device)
        # Loss distances are in pixels at the reference (full sensor) width, see LossWeights.
        self.px_scale = torch.tensor([self.config.reference_width_px / c.width for c in self.cameras],
                                     dtype=dtype, device=self.device)
        self.silhouette_ids = torch.as_tensor(
            farthest_point_ids(arrays.v_template, self.config.silhouette_vertices), device=self.device)
        bank = pose_bank if pose_bank is not None else pose_sampler.pose_bank(2048, seed=0, arrays=arrays)
        self.pose_bank = torch.as_tensor(np.asarray(bank), dtype=dtype, device=self.device)
        self.limit_frames = limits.joint_frames(arrays)
        self._limit_penalty = limits.joint_limit_penalty
        if init_poses is None:
            init_poses = np.stack(list(pose_sampler.canonical_poses(arrays).values()))
        self.init_coefficients = self._to_coefficients(np.asarray(init_poses, dtype=np.float64))
        with torch.no_grad():  # the candidates' rest keypoints and wrists, for every fit's placement
            rest = self.layer(pose=self._tensor(self.init_coefficients), batch_size=len(self.init_coefficients))
        self._candidates = (rest.keypoints.double().cpu().numpy(), rest.joints[:, 0].double().cpu().numpy())
        # Levenberg-Marquardt works in float64 whatever `dtype`: its hand-model Jacobians are forward
        # differences, and its per-step work is small enough that float64 costs little (measured).
        lm = torch.float64
        self.kinematics = FitKinematics(arrays, self.silhouette_ids.cpu().numpy(), k, lm, self.device)
        self.objective = Objective(self.kinematics, stack_cameras(self.cameras, lm, self.device),
                                   self.px_scale.to(lm),
                                   torch.as_tensor(np.asarray(bank), dtype=lm, device=self.device),
                                   self.limit_frames, self.config)

    # -- parameter helpers -------------------------------------------------------------------------
    def _to_coefficients(self, poses: np.ndarray) -> np.ndarray:
        """Absolute articulations (M, 45) -> PCA coefficients (M, k) (least squares)."""
        comps = self.arrays.hands_components[: self.config.num_pca_comps]  # (k, 45)
        coeffs, *_ = np.linalg.lstsq(comps.T, (poses - self.arrays.hands_mean).T, rcond=None)
        return coeffs.T

    def _tensor(self, value: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.asarray(value), dtype=self.dtype, device=self.device)

    # -- public API --------------------------------------------------------------------------------
    def fit(self, frames: list[FrameObservations], progress: ProgressCallback | None = None,
            prepared: PreparedMasks | None = None) -> list[FitResult]:
        """Fit every frame (optimised together as one batch). Raises FitInputError on bad input.

        `prepared`: the frames' `prepare_masks`, where the caller fits them more than once; made here otherwise."""
        with self._fit_threads():
            return self._fit(frames, progress, prepared=prepared)

    def prepare_masks(self, frames: list[FrameObservations]) -> PreparedMasks:
        """What the fits of these frames derive from their masks alone (`PreparedMasks`), for `fit` and `refine` to
        share: frames fitted twice pay for their distance fields and undistorted mask pixels once."""
        return prepare_masks(frames, self.cameras, self.config.cut_forearm)

    def refine(self, frames: list[FrameObservations], earlier: list[FitResult],
               progress: ProgressCallback | None = None,
               prepared: PreparedMasks | None = None) -> list[FitResult]:
        """Continue each frame's earlier fit on changed observations of the same frame (reweighted keypoints):
        the second stage only (every parameter, silhouettes against masks cut at the earlier fit's wrist), started
        from the earlier fit's parameters; no placement, no first stage, no other starts. Raises FitInputError on
        bad input or where `earlier` does not pair one to one with `frames`.

        The articulation restarts from the earlier fit's PCA coefficients (least squares of its pose, exact with
        all 45 components). Adam restarts its moments and learning-rate schedule, so it moves a converged fit
        before it settles again; Levenberg-Marquardt (the default) only takes steps that lower the objective."""
        if len(earlier) != len(frames):
            raise FitInputError(f"refine needs one earlier fit per frame: {len(earlier)} fits, {len(frames)} frames")
        for i, result in enumerate(earlier):
            if result.hand_model != self.arrays.name:
                raise FitInputError(f"frame {i}: the earlier fit is of hand model {result.hand_model!r}, this engine "
                                    f"fits {self.arrays.name!r}")
        with self._fit_threads():
            return self._fit(frames, progress, earlier, prepared)

    @contextmanager
    def _fit_threads(self) -> Iterator[None]:
        """torch's intra-op threads set to `FitConfig.torch_threads` (when given) for the duration, then restored."""
        threads = self.config.torch_threads
        previous = torch.get_num_threads()
        if threads:
            torch.set_num_threads(threads)
        try:
            yield
        finally:
            torch.set_num_threads(previous)

    def _fit(self, frames: list[FrameObservations], progress: ProgressCallback | None,
             earlier: list[FitResult] | None = None, prepared: PreparedMasks | None = None) -> list[FitResult]:
        if not frames:
            raise FitInputError("no frames to fit")
        if prepared is not None and not prepared.matches(frames):
            raise ValueError("prepared masks must be prepare_masks() of these frames' masks, in order")
        for i, obs in enumerate(frames):
            try:
                obs.validate(self.cameras)
            except FitInputError as exc:
                raise FitInputError(f"frame {i}: {exc}") from None
        started = time.perf_counter()
        cfg = self.config
        torch.manual_seed(cfg.seed)
        B = len(frames)
        notify = progress or (lambda fraction, message: None)
        clicks = self._tensor(np.stack([np.nan_to_num(f.clicks_px, nan=0.0) for f in frames]))
        click_w = self._tensor(np.stack([f.click_weights for f in frames]))
        kp3d, kp3d_w = self._targets_3d(frames)
        targets = Targets(clicks, click_w, kp3d, kp3d_w)
        if earlier is not None:
            start = self._earlier_vectors(earlier)
            if cfg.optimizer == "adam":
                params, terms, silhouettes, iterations = self._fit_adam(frames, targets, None, notify, prepared, start)
            else:
                params, terms, silhouettes, iterations = self._refine_lm(frames, targets, start, notify, prepared)
        elif cfg.optimizer == "adam":
            params, terms, silhouettes, iterations = self._fit_adam(frames, targets, self._placements(frames), notify,
                                                                    prepared)
        else:
            params, terms, silhouettes, iterations = self._fit_lm(frames, targets, self._placements(frames), notify,
                                                                  prepared)
        with torch.no_grad():
            out = self._forward(params)
        notify(1.0, "done")
        seconds = (time.perf_counter() - started) / B
        return [self._result(b, frames[b], params, out, terms, silhouettes, int(iterations[b]), seconds)
                for b in range(B)]

    # -- Levenberg-Marquardt (default) ---------------------------------------------------------------
    _LAYOUT = (("global_orient", 3), ("transl", 3), ("coefficients", None), ("betas", 10))
    _STAGE1 = ("global_orient", "transl", "coefficients")  # shape frozen while the hand is placed
    _STAGE2 = ("global_orient", "transl", "coefficients", "betas")

    def _fit_lm(self, frames, targets: Targets, placements, notify, prepared: PreparedMasks | None):
        """Several starts per frame through stage 1 (keypoints), the best `finalists` of them (by the full
        objective) through stage 2 (silhouettes too); the start with the lowest objective wins."""
        cfg = self.config
        B = len(frames)
        M = min(cfg.start_candidates, len(placements[0]))
        targets = targets.to(torch.float64)
        starts = self._start_vectors(placements, M)  # (B * M, P), frame-major
        keypoint_targets = targets.repeat(M)
        stage1, steps1 = self._solve(starts, self._STAGE1, keypoint_targets, cfg.global_iterations,
                                     lambda i: notify(0.3 * i / max(cfg.global_iterations, 1), "placing the hand"),
                                     silhouette=False, coarse=True)
        cost1, _ = self.objective.evaluate(stage1, keypoint_targets, False, coarse=True)
        best1 = cost1.reshape(B, M).argmin(1)
        pick = torch.arange(B, device=self.device) * M + best1
        # Masks are cut at the wrist of each frame's best stage-1 model.
        silhouettes, targets = self._silhouette_targets(frames, stage1[pick], targets, prepared)
        silhouette = silhouettes is not None
        K = min(cfg.finalists, M)
        if K < M:
            full, _ = self.objective.evaluate(stage1, targets.repeat(M), silhouette)
            keep = full.reshape(B, M).topk(K, dim=1, largest=False).indices  # (B, K)
        else:
            keep = torch.arange(M, device=self.device).expand(B, M)
        rows = (torch.arange(B, device=self.device)[:, None] * M + keep).reshape(-1)
        finalist_targets = targets.repeat(K)
        stage2, steps2 = self._solve(stage1[rows], self._STAGE2, finalist_targets, cfg.full_iterations,
                                     lambda i: notify(0.3 + 0.7 * i / max(cfg.full_iterations, 1),
                                                      "fitting pose and shape"), silhouette=silhouette)
        final, _ = self.objective.evaluate(stage2, finalist_targets, silhouette)
        winner = final.reshape(B, K).argmin(1)
        chosen = torch.arange(B, device=self.device) * K + winner
        solved = stage2[chosen]
        iterations = steps1[rows[chosen]] + steps2[chosen]
        terms = self.objective.terms(solved, targets, silhouette)
        return self._params(solved), terms, silhouettes, iterations.cpu().numpy()

    def _refine_lm(self, frames, targets: Targets, start: torch.Tensor, notify, prepared: PreparedMasks | None):
        """Stage 2 from each frame's start vector (B, P) float64."""
        cfg = self.config
        targets = targets.to(torch.float64)
        silhouettes, targets = self._silhouette_targets(frames, start, targets, prepared)
        silhouette = silhouettes is not None
        solved, steps = self._solve(start, self._STAGE2, targets, cfg.full_iterations,
                                    lambda i: notify(i / max(cfg.full_iterations, 1), "refining pose and shape"),
                                    silhouette=silhouette)
        terms = self.objective.terms(solved, targets, silhouette)
        return self._params(solved), terms, silhouettes, steps.cpu().numpy()

    def _silhouette_targets(self, frames, vectors: torch.Tensor, targets: Targets,
                            prepared: PreparedMasks | None = None,
                            ) -> tuple[dict[str, torch.Tensor] | None, Targets]:
        """The silhouettes (None without masks or with silhouettes off), masks cut at the wrist of the models of
        `vectors` (B, P), and the float64 targets with them."""
        if not (self.config.use_silhouette and any(f.masks is not None for f in frames)):
            return None, targets
        with torch.no_grad():
            placed = self._forward(self._params(vectors))
        silhouettes = self._prepare_silhouettes(frames, placed.joints.double().cpu().numpy(),
                                                placed.vertices.double().cpu().numpy(), prepared)
        return silhouettes, self._with_silhouettes(targets, silhouettes).to(torch.float64)

    def _earlier_vectors(self, earlier: list[FitResult]) -> torch.Tensor:
        """Earlier fits -> (B, P) float64 parameter vectors (see `_LAYOUT`)."""
        coefficients = self._to_coefficients(np.stack([np.asarray(r.pose, dtype=np.float64) for r in earlier]))
        rows = [np.concatenate([r.global_orient, r.transl, c, r.betas]) for r, c in zip(earlier, coefficients,
                                                                                       strict=True)]
        return torch.as_tensor(np.stack(rows), dtype=torch.float64, device=self.device)

    def _columns(self, names: tuple[str, ...]) -> torch.Tensor:
        """Columns of the parameter vector (see `kinematics`) that hold the named parameters."""
        columns, start = [], 0
        for name, size in self._LAYOUT:
            size = size or self.config.num_pca_comps
            if name in names:
                columns.extend(range(start, start + size))
            start += size
        return torch.as_tensor(columns, dtype=torch.int64, device=self.device)

    def _params(self, vector: torch.Tensor) -> dict[str, torch.Tensor]:
        """(B, P) parameter vector -> named parameters in the engine's dtype."""
        params, start = {}, 0
        for name, size in self._LAYOUT:
            size = size or self.config.num_pca_comps
            params[name] = vector[:, start: start + size].to(self.dtype).contiguous()
            start += size
        return params

    def _start_vectors(self, placements, M: int) -> torch.Tensor:
        """The M best placements of each frame as (B * M, P) float64 parameter vectors, frame-major."""
        rows = []
        for ranked in placements:
            for placement in ranked[:M]:
                rows.append(np.concatenate([placement.global_orient, placement.transl,
                                            self.init_coefficients[placement.candidate], np.zeros(10)]))
        return torch.as_tensor(np.stack(rows), dtype=torch.float64, device=self.device)

    def _solve(self, start: torch.Tensor, names: tuple[str, ...], targets: Targets, iterations: int,
               tick: Callable[[int], None], silhouette: bool,
               coarse: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """Levenberg-Marquardt on the named parameters from start (B, P): solution and steps per row."""
        if iterations <= 0:
            return start, torch.zeros(len(start), dtype=torch.int64, device=self.device)
        objective = self.objective
        active = self._columns(names)
        every = max(1, iterations // 10)
        return levenberg_marquardt(
            lambda p, a: normal_equations(objective, p, targets, a, silhouette, coarse, active),
            lambda p: objective.evaluate(p, targets, silhouette, coarse),
            lambda take, new, old: new.where(take, old),
            start, active, LMSettings(iterations, self.config.lm_damping, self.config.lm_tolerance),
            tick=lambda i: tick(i) if i % every == 0 else None)

    def _with_silhouettes(self, targets: Targets, silhouettes: dict[str, torch.Tensor]) -> Targets:
        outside = silhouettes["outside"]
        B, C, H, W = outside.shape
        return Targets(targets.clicks, targets.click_weights, targets.keypoints_3d, targets.keypoint_3d_weights,
                       outside=outside.reshape(B, C, H * W), height=H, width=W, boundary=silhouettes["boundary"],
                       boundary_normals=silhouettes["normals"], boundary_weights=silhouettes["valid"].to(self.dtype),
                       view_weights=silhouettes["view_weights"], outside_cap=silhouettes["outside_cap"],
                       coverage_cap=silhouettes["coverage_cap"])

    # -- Adam (the paper's optimiser) ----------------------------------------------------------------
    def _fit_adam(self, frames, targets: Targets, placements, notify, prepared: PreparedMasks | None,
                  start: torch.Tensor | None = None):
        """One start per frame (the best placement); stage 1 from keypoints, stage 2 with silhouettes. Given
        `start` (B, P) (`refine`): stage 2 only, from there."""
        cfg = self.config
        if start is None:
            best = [ranked[0] for ranked in placements]
            start = self._start_vectors([[p] for p in best], 1)
        params = {name: value.requires_grad_() for name, value in self._params(start.to(self.dtype)).items()}
        clicks, click_w, kp3d, kp3d_w = targets.clicks, targets.click_weights, targets.keypoints_3d, \
            targets.keypoint_3d_weights
        first = cfg.global_iterations if placements is not None else 0
        total = first + cfg.full_iterations
        iterations = self._optimise([params[n] for n in self._STAGE1], params, first, clicks, click_w,
                                    kp3d, kp3d_w, None, lambda i: notify(i / total, "placing the hand"), coarse=True)
        silhouettes = None
        if cfg.use_silhouette and any(f.masks is not None for f in frames):
            with torch.no_grad():
                placed = self._forward(params)
            silhouettes = self._prepare_silhouettes(frames, placed.joints.double().cpu().numpy(),
                                                    placed.vertices.double().cpu().numpy(), prepared)
        iterations = iterations + self._optimise(
            [params[n] for n in self._STAGE2], params, cfg.full_iterations, clicks, click_w, kp3d, kp3d_w, silhouettes,
            lambda i: notify((first + i) / total, "fitting pose and shape"))
        with torch.no_grad():
            terms = self._loss_terms(params, clicks, click_w, kp3d, kp3d_w, silhouettes)
        return {k: v.detach() for k, v in params.items()}, terms, silhouettes, iterations

    # -- shared stages -------------------------------------------------------------------------------
    def _targets_3d(self, frames: list[FrameObservations]) -> tuple[torch.Tensor, torch.Tensor]:
        targets = np.zeros((len(frames), 21, 3))
        weights = np.zeros((len(frames), 21))
        for b, f in enumerate(frames):
            if f.keypoints_3d is None:
                continue
            kp = np.asarray(f.keypoints_3d, dtype=np.float64)
            w = np.ones(21) if f.keypoint_3d_weights is None else np.asarray(f.keypoint_3d_weights, float)
            ok = np.isfinite(kp).all(1) & (w > 0)
            targets[b, ok], weights[b, ok] = kp[ok], w[ok]
        return self._tensor(targets), self._tensor(weights)

    def _placements(self, frames: list[FrameObservations]) -> list[list[Placement]]:
        """Per frame, the candidate articulations placed on the triangulated clicks, best first."""
        candidate_kp, candidate_wrist = self._candidates
        ranked = []
        for b, obs in enumerate(frames):
            targets, weights = observed_points_3d(obs, self.cameras)
            try:
                ranked.append(rank_placements(candidate_kp, candidate_wrist, targets, weights))
            except ValueError as exc:
                raise FitInputError(f"frame {b}: {exc} (clicks agreeing across views, or 3D keypoints)") from None
        return ranked

    def _prepare_silhouettes(self, frames: list[FrameObservations], joints: np.ndarray, vertices: np.ndarray,
                             prepared: PreparedMasks | None = None) -> dict[str, torch.Tensor]:
        """Wrist-cut masks -> padded outside-distance fields (B, C, H, W), boundary samples (B, C, N, 2)."""
        cfg = self.config
        B, C = len(frames), len(self.cameras)
        N = cfg.boundary_points
        prepared = prepared or self.prepare_masks(frames)
        boundary = np.zeros((B, C, N, 2))
        normals = np.zeros((B, C, N, 2))
        valid = np.zeros((B, C, N), dtype=bool)
        view_w = np.zeros((B, C))
        cut_masks: list[list[np.ndarray | None]] = []
        for b, f in enumerate(frames):
            # Each frame samples with its own generator: a frame fits the same alone or in any batch.
            rng = np.random.default_rng(cfg.seed)
            row: list[np.ndarray | None] = []
            for c, cam in enumerate(self.cameras):
                if not prepared.has_mask[b, c]:
                    row.append(None)
                    continue
                mask = np.asarray(f.masks[c], dtype=bool)  # has_mask: the frame has masks
                # The model must lie inside the whole silhouette (forearm included: it may hide part
                # of the hand), and must cover the hand part, whose cut line is no real edge.
                hand = mask
                if cfg.cut_forearm and f.masks_include_forearm:
                    # Hand direction: wrist joint -> middle finger base (MANO joint 4). The model's silhouette is
                    # rendered only for a view that needs it (along the forearm: measured 36 ms a frame otherwise).
                    hand = cut_forearm(mask, cam, joints[b, 0], joints[b, 4] - joints[b, 0],
                                       model_silhouette=partial(model_mask, vertices[b], self.arrays.faces, cam),
                                       pixels=prepared.pixels[b][c])
                row.append(hand)
                pts, nrm = boundary_samples(hand, N, rng, exclude=mask & ~hand)
                boundary[b, c, : len(pts)], normals[b, c, : len(pts)], valid[b, c, : len(pts)] = pts, nrm, True
                view_w[b, c] = 1.0
            cut_masks.append(row)
        return {
            "outside": self._tensor(prepared.outside_px),  # shared, not copied: read only
            "boundary": self._tensor(boundary),
            "normals": self._tensor(normals),
            "valid": torch.as_tensor(valid, device=self.device),
            "view_weights": self._tensor(view_w),
            "cut_masks": cut_masks,  # type: ignore[dict-item]
            # Robust scales by kind of mask (FitConfig): foreground masks hold occluders, hand masks lack them.
            "outside_cap": self._tensor([cfg.silhouette_cap_px if f.masks_include_forearm
                                         else cfg.hand_mask_silhouette_cap_px for f in frames]),
            "coverage_cap": self._tensor([cfg.coverage_cap_px if f.masks_include_forearm
                                          else cfg.hand_mask_coverage_cap_px for f in frames]),
        }

    def _forward(self, params: dict[str, torch.Tensor]):
        return self.layer(betas=params["betas"], pose=params["coefficients"],
                          global_orient=params["global_orient"], transl=params["transl"])

    def _loss_terms(self, params, clicks, click_w, kp3d, kp3d_w, silhouettes, coarse: bool = False):
        cfg, w = self.config, self.config.weights
        out = self._forward(params)
        projected, _ = project_points_torch(out.keypoints, **self.cam)  # (B, C, 21, 2)
        terms = {
            "kp2d": w.kp2d * losses.keypoint_2d_loss(projected, clicks, click_w, self.px_scale, cfg.robust,
                                                     cfg.robust_scale_px),
            "shape": w.shape * losses.shape_prior(params["betas"]),
            "pose": w.pose * losses.pca_pose_prior(params["coefficients"]),
            "nn": w.nn * losses.nearest_pose_prior(out.full_pose[:, 3:], self.pose_bank, cfg.nn_neighbours),
            "limits": w.limits * self._limit_penalty(out.full_pose[:, 3:], self.limit_frames),
        }
        if w.kp3d > 0 and bool(kp3d_w.sum() > 0):
            terms["kp3d"] = w.kp3d * losses.keypoint_3d_loss(out.keypoints, kp3d, kp3d_w)
        elif bool(kp3d_w.sum() > 0) and coarse:
            # Without a 3D weight (round 0) given 3D points still help placement in the first stage.
            terms["kp3d"] = 100.0 * losses.keypoint_3d_loss(out.keypoints, kp3d, kp3d_w)
        if silhouettes is not None and not coarse:
            verts = out.vertices[:, self.silhouette_ids]
            verts_px, _ = project_points_torch(verts, **self.cam)  # (B, C, Vs, 2)
            outside = losses.silhouette_outside_loss(verts_px, silhouettes["outside"], silhouettes["view_weights"],
                                                     self.px_scale, silhouettes["outside_cap"])
            cover = losses.silhouette_coverage_loss(verts_px, silhouettes["boundary"], silhouettes["valid"],
                                                    silhouettes["view_weights"], self.px_scale,
                                                    silhouettes["coverage_cap"],
                                                    silhouettes["normals"], cfg.coverage_tangent_weight)
            terms["seg"] = w.seg * (outside + cover)
        return terms

    def _optimise(self, variables, params, iterations, clicks, click_w, kp3d, kp3d_w, silhouettes,
                  tick: Callable[[int], None], coarse: bool = False) -> np.ndarray:
        """Adam (the paper's optimiser) on `variables` with the loss functions of `losses.py`; steps per frame."""
        B = len(params["transl"])
        if iterations <= 0:
            return np.zeros(B, dtype=np.int64)
        lr = self.config.learning_rate
        groups = [{"params": [v], "lr": lr * (0.2 if v is params["transl"] else 1.0)} for v in variables]
        optimizer = torch.optim.Adam(groups)
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=iterations, eta_min=lr * 0.05)
        every = max(1, iterations // 20)
        for i in range(iterations):
            optimizer.zero_grad(set_to_none=True)
            terms = self._loss_terms(params, clicks, click_w, kp3d, kp3d_w, silhouettes, coarse=coarse)
            torch.stack(list(terms.values())).sum().backward()
            optimizer.step()
            schedule.step()
            if i % every == 0:
                tick(i)
        return np.full(B, iterations, dtype=np.int64)

    # -- results -------------------------------------------------------------------------------------
    def _result(self, b, obs, params, out, terms, silhouettes, iterations, seconds) -> FitResult:
        vertices = out.vertices[b].double().cpu().numpy()
        keypoints = out.keypoints[b].double().cpu().numpy()
        faces = self.arrays.faces
        masks = tuple(model_mask(vertices, faces, cam) for cam in self.cameras)
        iou = np.full(len(self.cameras), np.nan)
        given = silhouettes["cut_masks"][b] if silhouettes is not None else [None] * len(self.cameras)
        for c, (model, target) in enumerate(zip(masks, given, strict=True)):
            if target is not None:
                union = np.logical_or(model, target).sum()
                iou[c] = np.logical_and(model, target).sum() / union if union else np.nan
        projected, _ = project_points_torch(out.keypoints[b: b + 1].double(),
                                            **{k: v.double() for k, v in self.cam.items()})
        residual_2d = np.linalg.norm(projected[0].cpu().numpy() - obs.clicks_px, axis=-1)
        residual_2d[obs.click_weights <= 0] = np.nan
        residual_3d = np.full(21, np.nan)
        if obs.keypoints_3d is not None:
            residual_3d = 1000 * np.linalg.norm(keypoints - np.asarray(obs.keypoints_3d), axis=1)
        diagnostics = FitDiagnostics(
            iou_per_view=iou,
            residual_2d_px=residual_2d,
            residual_3d_mm=residual_3d,
            loss_terms={name: float(value[b]) for name, value in terms.items()},
            iterations=iterations,
            seconds=seconds,
            accepted_2d=None if obs.from_proposal is None else np.asarray(obs.from_proposal, dtype=bool).copy(),
            points_source=obs.points_source,
        )
        return FitResult(
            betas=params["betas"][b].detach().double().cpu().numpy(),
            pose=out.full_pose[b, 3:].detach().double().cpu().numpy(),
            global_orient=params["global_orient"][b].detach().double().cpu().numpy(),
            transl=params["transl"][b].detach().double().cpu().numpy(),
            vertices=vertices,
            keypoints=keypoints,
            model_masks=masks,
            diagnostics=diagnostics,
            hand_model=self.arrays.name,
        )
