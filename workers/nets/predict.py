"""Prediction: hand masks (HandSegNet), hand localisation, 3D keypoints with confidence (MVNet).

Confidence (paper eq. 8): per keypoint the maximum of its score volume; per sample their mean. For a
soft-argmax network the maximum of its softmax volume ("latent heat map", supplementary).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from workers.capture.reader import load_frame_images, load_frame_masks
from workers.capture.schema import FrameRef
from workers.geometry.camera import Camera
from workers.geometry.projection import stack_cameras
from workers.nets.data import crop_views
from workers.nets.detections import DetectionCache, FrameDetections, detect_frames, stack_detections
from workers.nets.handsegnet import HandSegNet
from workers.nets.keypoint_maps import image_to_crop_px
from workers.nets.localisation import HandLocation, LocalisationError, localise_hand
from workers.nets.losses import grid_to_world, refined_argmax, soft_argmax, world_to_grid
from workers.nets.mvnet import MVNet

log = logging.getLogger(__name__)

Views = Sequence[np.ndarray] | Mapping[str, np.ndarray]


@dataclass(frozen=True)
class KeypointPrediction:
    """MVNet's output for N frames.

    Attributes:
        keypoints_3d: (N, 21, 3) float64 metres, world frame (NaN for frames that could not be localised).
        confidence: (N, 21) per-keypoint confidence (max of the score volume); 0 where not predicted.
        sample_confidence: (N,) mean over the keypoints (eq. 8).
        centers_world: (N, 3) the voxel grids' centres, metres, world frame.
    """

    keypoints_3d: np.ndarray
    confidence: np.ndarray
    sample_confidence: np.ndarray
    centers_world: np.ndarray


def _model_device(model: torch.nn.Module) -> torch.device:
    return next(model.parameters()).device


def ordered_views(images: Views, cameras: Sequence[Camera], what: str = "image") -> list[np.ndarray]:
    """Images in camera order from a list or a {camera name: image} mapping; checks count and sizes."""
    if isinstance(images, Mapping):
        missing = [c.name for c in cameras if c.name not in images]
        if missing:
            raise ValueError(f"missing view(s) {missing}: every camera of the rig needs an {what}")
        images = [images[c.name] for c in cameras]
    if len(images) != len(cameras):
        raise ValueError(f"got {len(images)} views for {len(cameras)} cameras (missing view?)")
    for image, cam in zip(images, cameras, strict=True):
        if image is None:
            raise ValueError(f"missing view {cam.name}")
        if image.shape[:2] != (cam.height, cam.width):
            raise ValueError(f"{what} of {cam.name} is {image.shape[1]}x{image.shape[0]} px, the calibration says "
                             f"{cam.width}x{cam.height}")
    return list(images)


def readout(model: MVNet, scores: torch.Tensor,
            window_grid: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Score volumes (B, K, N, N, N) -> keypoints in voxel indices (B, K, 3) and confidence (B, K).

    window_grid: (B, K, 3) voxel indices (NaN: none) around which the peak is looked for, within the configuration's
    `detector_window_m` (`window_scores`); None: the whole grid."""
    if window_grid is not None and model.config.detector_window_m > 0:
        radius = model.config.detector_window_m / model.config.voxel_m
        scores = window_scores(scores, window_grid, radius)
    if model.config.loss == "softargmax":
        return soft_argmax(scores)
    return refined_argmax(scores)


def window_scores(scores: torch.Tensor, centers_grid: torch.Tensor, radius_voxels: float) -> torch.Tensor:
    """Score volumes with every voxel farther than `radius_voxels` from its keypoint's window centre set to -inf.

    Why: fed the detector's lifted keypoints, the U-Net's medians equal the lift's, but where its volume peaks far
    from the lift it is confidently wrong (issue 15's sim, round 1: 96 keypoints over 30 mm from the lift, 127 mm
    from the truth at median confidence 0.85, the lift 43 mm). Within the window the network refines the lift;
    its confidence (eq. 8) is the peak inside it, so a volume that peaks elsewhere reads as unsure.

    Args:
        scores: (B, K, N, N, N).
        centers_grid: (B, K, 3) continuous voxel indices (i, j, k as the volume's axes); a NaN row, or a window
            holding no voxel centre (a lift outside the grid), leaves that keypoint's volume whole.
        radius_voxels: window radius in voxels.
    """
    N = scores.shape[-1]
    axis = torch.arange(N, device=scores.device, dtype=torch.float32)  # float32 even for bf16 scores: exact indices
    c = torch.nan_to_num(centers_grid.to(torch.float32), nan=float("inf"))
    d2 = ((axis - c[..., 0, None]) ** 2)[..., :, None, None] + ((axis - c[..., 1, None]) ** 2)[..., None, :, None] \
        + ((axis - c[..., 2, None]) ** 2)[..., None, None, :]  # (B, K, N, N, N)
    inside = d2 <= radius_voxels**2
    inside = inside | ~inside.flatten(2).any(dim=-1)[..., None, None, None]
    return scores.masked_fill(~inside, float("-inf"))


@torch.no_grad()
def predict_from_crops(model: MVNet, crops: np.ndarray, K_crop: np.ndarray, centers_world: np.ndarray,
                       cameras: Sequence[Camera], view_valid: np.ndarray | None = None,
                       batch_frames: int = 4, detector_px: np.ndarray | None = None,
                       detector_scores: np.ndarray | None = None,
                       detector_world: np.ndarray | None = None) -> KeypointPrediction:
    """MVNet on prepared crops.

    Args:
        crops: (N, C, S, S, 3) uint8; K_crop: (N, C, 3, 3); centers_world: (N, 3) metres;
        view_valid: (N, C) bool (default all); cameras: the C cameras.
        detector_px: (N, C, K, 2) the detector's keypoints in crop pixels, detector_scores: (N, C, K) their
            weights (keypoint_maps.image_to_crop_px; a detector-backed MVNet needs them).
        detector_world: (N, K, 3) the detector's lifted (and offset-corrected) keypoints, metres, world frame, NaN
            where not lifted: with the configuration's `detector_window_m` the readout looks for each keypoint
            within that distance of its lift (`window_scores`); None: the whole grid.
    """
    if model.config.heatmap_source == "detector" and (detector_px is None or detector_scores is None):
        raise ValueError("a detector-backed MVNet needs the detector's keypoints (detector_px, detector_scores)")
    model.eval()
    device = _model_device(model)
    cams = stack_cameras(list(cameras), device=device)
    cfg = model.config
    N = crops.shape[0]
    keypoints = np.zeros((N, 21, 3))
    confidence = np.zeros((N, 21))
    valid = np.ones(crops.shape[:2], bool) if view_valid is None else view_valid
    for s in range(0, N, batch_frames):
        sl = slice(s, s + batch_frames)
        centers = torch.as_tensor(centers_world[sl], dtype=torch.float32, device=device)
        detector = {} if model.config.heatmap_source != "detector" else {
            "detector_px": torch.as_tensor(detector_px[sl], dtype=torch.float32, device=device),
            "detector_scores": torch.as_tensor(detector_scores[sl], dtype=torch.float32, device=device)}
        scores = model(torch.as_tensor(crops[sl], device=device),
                       torch.as_tensor(K_crop[sl], dtype=torch.float32, device=device), cams["dist"], cams["R"],
                       cams["t"], centers, torch.as_tensor(valid[sl], device=device), **detector)
        window = None if detector_world is None else world_to_grid(
            torch.as_tensor(detector_world[sl], dtype=torch.float32, device=device), centers, cfg.grid_size,
            cfg.grid_side_m)
        grid, conf = readout(model, scores, window)
        keypoints[sl] = grid_to_world(grid, centers, cfg.grid_size, cfg.grid_side_m).cpu().numpy()
        confidence[sl] = conf.cpu().numpy()
    return KeypointPrediction(keypoints, confidence, confidence.mean(axis=1), np.asarray(centers_world, float))


def predict_keypoints(model: MVNet, frames_views: Sequence[Views], cameras: Sequence[Camera],
                      centers_world: np.ndarray, batch_frames: int = 4,
                      detections: Sequence[FrameDetections] | None = None) -> KeypointPrediction:
    """3D keypoints and confidence of N frames.

    Args:
        model: a trained MVNet (checkpoints.load_model).
        frames_views: N frames, each C images (H_c, W_c, 3) uint8 RGB in camera order or by camera name.
        cameras: the rig's C cameras (image sizes are checked against them).
        centers_world: (N, 3) hand centres (localise_hand, or FrameDetections.center_world), metres, world frame.
        detections: N frames' detections (detections.detect_frames); a detector-backed MVNet needs them.
    Returns:
        KeypointPrediction.
    """
    if detections is not None and len(detections) != len(frames_views):
        raise ValueError(f"got {len(detections)} detections for {len(frames_views)} frames")
    if model.config.heatmap_source == "detector" and detections is None:
        raise ValueError("a detector-backed MVNet needs the frames' detections (detections.detect_frames)")
    centers_world = np.asarray(centers_world, float)
    if centers_world.shape != (len(frames_views), 3):
        raise ValueError(f"centers_world must be ({len(frames_views)}, 3), got {centers_world.shape}")
    cfg = model.config
    prepared = [crop_views(ordered_views(v, cameras), cameras, c, cfg.crop_px, cfg.crop_radius_m)
                for v, c in zip(frames_views, centers_world, strict=True)]
    crops = np.stack([p[0] for p in prepared])
    K_crop = np.stack([p[1] for p in prepared])
    valid = np.stack([p[2] for p in prepared])
    det_px = det_scores = det_world = None
    if model.config.heatmap_source == "detector" and detections is not None:
        offsets = model.keypoint_offsets()
        if offsets is not None:  # as training corrected its detections (data.build_mvnet_dataset)
            detections = [d.corrected(offsets, cameras) for d in detections]
        px, det_scores = stack_detections(detections)
        det_px = image_to_crop_px(px, K_crop, np.stack([np.asarray(c.K, np.float64) for c in cameras]))
        det_world = np.stack([d.points_world for d in detections])
    return predict_from_crops(model, crops, K_crop, centers_world, cameras, valid, batch_frames, det_px, det_scores,
                              det_world if model.config.heatmap_source == "detector" else None)


@torch.no_grad()
def segment(model: HandSegNet, images: Sequence[np.ndarray]) -> list[np.ndarray]:
    """HandSegNet on whole inputs: images (H, W, 3) uint8 RGB (equal sizes are batched) -> one (H, W) float32
    hand probability map each."""
    model.eval()
    device = _model_device(model)
    out: list[np.ndarray | None] = [None] * len(images)
    groups: dict[tuple[int, ...], list[int]] = {}
    for i, image in enumerate(images):
        if image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"image {i} must be (H, W, 3) RGB, got {image.shape}")
        groups.setdefault(image.shape, []).append(i)
    for indices in groups.values():
        batch = torch.as_tensor(np.stack([images[i] for i in indices]), device=device)
        prob = torch.sigmoid(model(batch)).cpu().numpy()
        for i, p in zip(indices, prob, strict=True):
            out[i] = p.astype(np.float32)
    return out  # type: ignore[return-value]


@dataclass(frozen=True)
class MaskPrediction:
    """HandSegNet's output for one frame.

    Attributes:
        probabilities: C maps (H_c, W_c) float32 in [0, 1], camera order, at the images' resolution.
        location: the hand found from them (None when fewer than two views show it).
    """

    probabilities: list[np.ndarray]
    location: HandLocation | None


def _gate(probabilities: list[np.ndarray], foreground: list[np.ndarray] | None) -> list[np.ndarray]:
    """Hand probabilities limited to the (dilated) foreground masks, when there are some."""
    if foreground is None:
        return probabilities
    return [p * f for p, f in zip(probabilities, foreground, strict=True)]


def predict_masks(model: HandSegNet, views: Views, cameras: Sequence[Camera], refine_passes: int = 2,
                  foreground: Views | None = None) -> MaskPrediction:
    """Hand masks of one multi-view frame.

    A coarse pass over each whole image localises the hand (blob centroids triangulated, see
    localisation.py), a pass on crops of an intermediate radius refines it; a fine pass on the crop around
    that centre gives the probabilities, warped back into the image (zero outside the crop); the location
    is triangulated again from the fine masks and, when it moved by more than 1 cm, the fine pass is
    repeated on crops around it (at most `refine_passes` times).

    Args:
        model: a trained HandSegNet.
        views: C images (H_c, W_c, 3) uint8 RGB, camera order or by camera name.
        cameras: the rig.
        foreground: optional C (H_c, W_c) foreground masks (chroma key of a green-screen frame: hand, forearm
            and held object); the hand probabilities are limited to them (dilated by 2 px), so nothing of the
            background can pass for the hand.
    Returns:
        MaskPrediction (all-zero probabilities and no location when the coarse pass finds no hand).
    """
    cfg = model.config
    images = ordered_views(views, cameras)
    gate = None
    if foreground is not None:
        kernel = np.ones((5, 5), np.uint8)
        gate = [cv2.dilate((np.asarray(f) > 0.5).astype(np.uint8), kernel).astype(np.float32)
                for f in ordered_views(foreground, cameras, "foreground mask")]
    coarse_cams, coarse_images, coarse_gate = [], [], []
    for c, (image, cam) in enumerate(zip(images, cameras, strict=True)):
        depth0 = abs(float(cam.t[2]))  # depth of the world origin (the rig's centre)
        scale = cfg.crop_px / (2 * cfg.coarse_radius_m) * depth0 / float(cam.K[0, 0])
        width = max(16, round(cam.width * scale))
        small = cam.scaled(width)
        coarse_cams.append(small)
        coarse_images.append(cv2.resize(image, (small.width, small.height), interpolation=cv2.INTER_AREA))
        if gate is not None:
            coarse_gate.append(cv2.resize(gate[c], (small.width, small.height), interpolation=cv2.INTER_AREA))
    coarse = _gate(segment(model, coarse_images), coarse_gate if gate is not None else None)
    medium_radius_m = float(np.sqrt(cfg.crop_radius_m * cfg.coarse_radius_m))
    try:
        location = localise_hand([p > cfg.threshold for p in coarse], coarse_cams, min_area_px=4)
    except LocalisationError as exc:
        # At the coarse scale a low-contrast hand (pale skin on grey texture) can vanish; look again at the
        # intermediate scale around the point the cameras look at.
        log.info("coarse pass found no hand (%s); searching around the rig's centre", exc)
        try:
            medium = _gate(_fine_pass(model, images, cameras, rig_center(cameras), medium_radius_m), gate)
            location = localise_hand([p > cfg.threshold / 2 for p in medium], cameras)  # a weak hand is better
        except LocalisationError as exc2:
            log.info("no hand found: %s", exc2)
            return MaskPrediction([np.zeros((c.height, c.width), np.float32) for c in cameras], None)
    else:
        # An intermediate scale next: at the coarse scale the hand is ~20 px and the wrist cut is blurred.
        with contextlib.suppress(LocalisationError):
            medium = _gate(_fine_pass(model, images, cameras, location.center_world, medium_radius_m), gate)
            location = localise_hand([p > cfg.threshold for p in medium], cameras)
    probabilities = _gate(_fine_pass(model, images, cameras, location.center_world), gate)
    for attempt in range(refine_passes + 1):
        try:
            refined = localise_hand([p > cfg.threshold for p in probabilities], cameras)
        except LocalisationError:
            break  # keep the previous location
        moved_m = float(np.linalg.norm(refined.center_world - location.center_world))
        location = refined
        if moved_m < 0.01 or attempt == refine_passes:
            break
        probabilities = _gate(_fine_pass(model, images, cameras, location.center_world), gate)  # re-centred
    return MaskPrediction(probabilities, location)


def rig_center(cameras: Sequence[Camera]) -> np.ndarray:
    """The point closest (least squares) to all cameras' optical axes, (3,) metres, world frame: where a
    rig looks, the centre of its capture volume."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        R = np.asarray(cam.R, float)
        center = -R.T @ np.asarray(cam.t, float)
        axis = R[2] / np.linalg.norm(R[2])  # the optical axis (camera z) in world coordinates
        P = np.eye(3) - np.outer(axis, axis)  # projector onto the plane normal to the axis
        A += P
        b += P @ center
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _fine_pass(model: HandSegNet, images: list[np.ndarray], cameras: Sequence[Camera],
               center_world: np.ndarray, radius_m: float | None = None) -> list[np.ndarray]:
    """HandSegNet on the crops of half side `radius_m` (default: the fine radius) around `center_world`,
    warped back into each image (zero outside the crop)."""
    cfg = model.config
    crops, K_crop, valid, _ = crop_views(images, cameras, center_world, cfg.crop_px, radius_m or cfg.crop_radius_m)
    fine = segment(model, list(crops))
    probabilities = []
    for c, cam in enumerate(cameras):
        if not valid[c]:
            probabilities.append(np.zeros((cam.height, cam.width), np.float32))
            continue
        A = K_crop[c] @ np.linalg.inv(cam.K)
        probabilities.append(cv2.warpAffine(fine[c], A[:2], (cam.width, cam.height),
                                            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                            borderMode=cv2.BORDER_CONSTANT, borderValue=0))
    return probabilities


@dataclass(frozen=True)
class FramePrediction:
    """Predictions for N frames: keypoints (NaN where localisation failed), masks per frame (C probability
    maps, or the chroma-key masks used), locations (None where failed)."""

    keypoints: KeypointPrediction
    masks: list[list[np.ndarray]]
    locations: list[HandLocation | None]


def predict_frames(mvnet: MVNet, frames: Sequence[FrameRef], cameras: Sequence[Camera],
                   handsegnet: HandSegNet | None = None, batch_frames: int = 4, *, handedness: str = "right",
                   detection_cache: DetectionCache | None = None) -> FramePrediction:
    """The worker's path: images -> masks (HandSegNet, else the chroma-key masks) -> hand centre -> MVNet.

    HandSegNet's masks of a green-screen frame are limited to its chroma-key foreground (the hand is part
    of it; nothing outside can be hand). Frames whose hand cannot be localised get NaN keypoints and zero
    confidence. A detector-backed MVNet (heatmap_source="detector") also gets the detector's keypoints,
    found inside the chroma-key masks where the frame has some (through `detection_cache`), else inside
    HandSegNet's, and its grid centre is their lifted keypoints' robust centroid where enough were lifted
    (else the masks' location).

    Raises:
        DetectorUnavailableError: a detector-backed MVNet and the model files are missing (choose the
            configuration with detections.detector_backed first).
    """
    use_detector = mvnet.config.heatmap_source == "detector"
    views_all, masks_all, locations, detections = [], [], [], []
    for frame in frames:
        views = ordered_views(load_frame_images(frame, cameras), cameras)
        location: HandLocation | None
        if handsegnet is not None:
            chroma = load_frame_masks(frame) if frame.mask_paths else {}
            foreground = [chroma[c.name] for c in cameras] if chroma and all(c.name in chroma for c in cameras) \
                else None
            prediction = predict_masks(handsegnet, views, cameras, foreground=foreground)
            masks, location = prediction.probabilities, prediction.location
        else:
            chroma = load_frame_masks(frame)
            if not chroma:
                raise ValueError(f"frame {frame.sequence_id}/{frame.index} has no chroma-key masks; pass a "
                                 "trained HandSegNet")
            masks = [chroma[c.name].astype(np.float32) for c in cameras]
            try:
                location = localise_hand(masks, cameras)
            except LocalisationError:
                location = None
        if use_detector:
            if handsegnet is not None and not frame.mask_paths:
                binary = [p > handsegnet.config.threshold for p in masks]
                found = detect_frames([frame], cameras, handedness=handedness, images=lambda _f, v=views: v,
                                      masks=lambda _f, b=binary: b)[0]
            else:  # a chroma key locates the hand for the detector better than HandSegNet (and is cacheable)
                found = detect_frames([frame], cameras, handedness=handedness, images=lambda _f, v=views: v,
                                      cache=detection_cache)[0]
            detections.append(found)
            center = found.center_world()
            if center is not None:  # the detector's centre; the masks' boxes stay where there are some
                location = dataclasses.replace(location, center_world=center) if location is not None else \
                    HandLocation(center, np.full((len(cameras), 4), np.nan), (found.scores > 0).any(axis=1),
                                 float("nan"))
        if location is None:
            log.warning("frame %s/%d: the hand could not be localised", frame.sequence_id, frame.index)
        views_all.append(views)
        masks_all.append(masks)
        locations.append(location)
    ok = [i for i, loc in enumerate(locations) if loc is not None]
    N = len(frames)
    keypoints = np.full((N, 21, 3), np.nan)
    confidence = np.zeros((N, 21))
    centers = np.full((N, 3), np.nan)
    if ok:
        centers_ok = np.stack([locations[i].center_world for i in ok])  # type: ignore[union-attr]
        pred = predict_keypoints(mvnet, [views_all[i] for i in ok], cameras, centers_ok, batch_frames,
                                 [detections[i] for i in ok] if use_detector else None)
        keypoints[ok], confidence[ok], centers[ok] = pred.keypoints_3d, pred.confidence, centers_ok
    return FramePrediction(KeypointPrediction(keypoints, confidence, confidence.mean(axis=1), centers),
                           masks_all, locations)
