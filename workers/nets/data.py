"""Training data for MVNet and HandSegNet from captures, and their augmentation.

- Crops: a square around the projection of the hand centre, covering `crop_radius_m` either side at the
  centre's depth, resampled to `crop_px`; the crop's intrinsics K_crop = A K (A the crop's affine map,
  pixel-centre convention of docs/conventions.md), distortion unchanged.
- Augmentation (supplementary "Cut&Paste"): green-screen views get a new background through their
  chroma-key mask; plus colour gain/offset and, for MVNet, a random shift of the voxel grid's centre.
  The background pool is disjoint from the synthetic evaluation backgrounds (other scikit-image photos
  and procedural textures of our own), so evaluation stays on unseen backgrounds.
"""

from __future__ import annotations

import importlib.util
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import skimage.data

from workers.capture.reader import load_frame_images, load_frame_masks, load_ground_truth
from workers.capture.schema import Capture, FrameRef
from workers.detector.keypoint_offsets import KeypointOffsets
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points
from workers.nets.configs import HandSegNetConfig, MVNetConfig
from workers.nets.detections import DetectionCache, FrameDetections, detect_frames, stack_detections
from workers.nets.keypoint_maps import image_to_crop_px
from workers.nets.localisation import LocalisationError, localise_hand

log = logging.getLogger(__name__)

# scikit-image's bundled images that `handloop synth` does NOT use as evaluation backgrounds.
AUGMENTATION_PHOTOS: tuple[str, ...] = (
    "camera.png", "cell.png", "chessboard_RGB.png", "clock_motion.png", "coins.png", "color.png", "horse.png",
    "hubble_deep_field.jpg", "ihc.png", "logo.png", "microaneurysms.png", "moon.png", "page.png", "retina.jpg",
    "text.png",
)


def frame_id(frame: FrameRef) -> str:
    """A sample's id: "<sequence id>/<frame index>"."""
    return f"{frame.sequence_id}/{frame.index:06d}"


# --- crops -----------------------------------------------------------------------------------------------


def crop_transform(camera: Camera, center_world: np.ndarray, crop_px: int, crop_radius_m: float
                   ) -> tuple[np.ndarray, bool]:
    """The affine map A (3, 3) from image pixels to crop pixels, and whether the centre is in front.

    The crop's side in image pixels is 2 crop_radius_m fx / depth, centred on the centre's projection.
    """
    pixels, depth = project_points(np.asarray(center_world, np.float64)[None], [camera])
    u0, v0 = pixels[0, 0]
    z = float(depth[0, 0])
    if not (z > 1e-3 and np.isfinite(u0) and np.isfinite(v0)):
        return np.eye(3), False
    side_px = 2 * crop_radius_m * float(camera.K[0, 0]) / z
    a = crop_px / side_px
    # crop pixel centre i <-> image coordinate (u0 - side/2) + (i + 0.5) side / crop_px
    A = np.array([[a, 0, -(u0 - side_px / 2) * a - 0.5], [0, a, -(v0 - side_px / 2) * a - 0.5], [0, 0, 1.0]])
    return A, True


def crop_views(images: Sequence[np.ndarray], cameras: Sequence[Camera], center_world: np.ndarray, crop_px: int,
               crop_radius_m: float, masks: Sequence[np.ndarray | None] | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Crop every view around the hand centre.

    Args:
        images: C images (H_c, W_c, 3) uint8 RGB, camera order; sizes must match the cameras.
        cameras: the C cameras.
        center_world: (3,) hand centre, metres, world frame.
        crop_px: output side, pixels; crop_radius_m: half side at the centre's depth, metres.
        masks: optional C (H_c, W_c) bool masks (or None entries) cropped alike.
    Returns:
        crops (C, S, S, 3) uint8; K_crop (C, 3, 3) float64; valid (C,) bool (centre in front of the
        camera); mask crops (C, S, S) uint8 0 / 255 or None.
    """
    if len(images) != len(cameras):
        raise ValueError(f"got {len(images)} images for {len(cameras)} cameras")
    C = len(cameras)
    crops = np.zeros((C, crop_px, crop_px, 3), np.uint8)
    K_crop = np.zeros((C, 3, 3))
    valid = np.zeros(C, bool)
    mask_crops = np.zeros((C, crop_px, crop_px), np.uint8) if masks is not None else None
    for c, (image, cam) in enumerate(zip(images, cameras, strict=True)):
        if image is None or image.shape != (cam.height, cam.width, 3):
            got = None if image is None else image.shape
            raise ValueError(f"image of {cam.name} is {got}, expected ({cam.height}, {cam.width}, 3) uint8 RGB")
        A, valid[c] = crop_transform(cam, center_world, crop_px, crop_radius_m)
        K_crop[c] = A @ cam.K
        interp = cv2.INTER_AREA if A[0, 0] < 1 else cv2.INTER_LINEAR
        if valid[c]:
            src = image
            if A[0, 0] < 0.7:  # anti-alias before a strong reduction
                src = cv2.GaussianBlur(image, (0, 0), 0.45 / A[0, 0])
            crops[c] = cv2.warpAffine(src, A[:2], (crop_px, crop_px), flags=cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            if mask_crops is not None and masks[c] is not None:
                mask_crops[c] = cv2.warpAffine(masks[c].astype(np.uint8) * 255, A[:2], (crop_px, crop_px),
                                               flags=interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return crops, K_crop, valid, mask_crops


# --- backgrounds for cut-and-paste ---------------------------------------------------------------------------


def scene_photo_paths() -> tuple[Path, ...]:
    """Photographs of real scenes that installed packages ship (no download): viser's environment maps
    (a forest slope, a park, a warehouse, interiors, streets at 1024 x 512) and matplotlib's sample photo.
    None of them is a synthetic evaluation background; missing files are skipped."""

    paths: list[Path] = []
    spec = importlib.util.find_spec("viser")
    if spec is not None and spec.origin:
        paths += sorted((Path(spec.origin).parent / "_assets" / "hdri").glob("*.jpg"))
    spec = importlib.util.find_spec("matplotlib")
    if spec is not None and spec.origin:
        paths += sorted((Path(spec.origin).parent / "mpl-data" / "sample_data").glob("grace_hopper.jpg"))
    return tuple(paths)


@lru_cache(maxsize=1)
def augmentation_backgrounds() -> tuple[np.ndarray, ...]:
    """The background pool: (H, W, 3) uint8 RGB images: bundled scikit-image photos not used for evaluation
    and the installed packages' scene photographs (`scene_photo_paths`)."""

    root = Path(skimage.data.__file__).parent
    out = []
    for path in [root / name for name in AUGMENTATION_PHOTOS] + list(scene_photo_paths()):
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            continue
        out.append(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
    if not out:
        log.warning("no bundled photos found for cut-and-paste; using procedural backgrounds only")
    return tuple(out)


def _noise_field(height: int, width: int, rng: np.random.Generator, cells: int) -> np.ndarray:
    """(H, W) float32 smooth noise in about [-1, 1]."""
    coarse = rng.uniform(-1, 1, (cells, cells)).astype(np.float32)
    return cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)


def procedural_background(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A procedural background (H, W, 3) float32 0..255 of our own (not the synthetic evaluation's): a
    muted base colour with one of: multi-scale texture (foliage, gravel, fabric), flat rectangles with
    shading (walls, furniture), a smooth gradient, or saturated colour blobs."""
    base = rng.uniform(0, 1, 3) ** 1.5 * 255
    kind = rng.random()
    if kind < 0.15:  # grey fine-grained texture (foliage, gravel, fabric in grey light): high-frequency noise
        fine = sum(_noise_field(height, width, rng, max(4, height // k)) * w for k, w in ((2, 1.0), (4, 0.7), (8, 0.4)))
        out = np.repeat((base.mean() + rng.uniform(30, 70) * fine)[..., None], 3, axis=2) * rng.uniform(0.9, 1.1, 3)
    elif kind < 0.4:  # texture: noise at two scales, coloured around the base
        amount = rng.uniform(15, 70)
        out = base + amount * (_noise_field(height, width, rng, int(rng.integers(4, 24)))[..., None]
                               * rng.uniform(0.5, 1.0, 3) + 0.6 * _noise_field(height, width, rng, max(height // 3, 8))
                               [..., None])
    elif kind < 0.7:  # rectangles: flat surfaces with a gentle illumination gradient
        out = np.broadcast_to(base, (height, width, 3)).astype(np.float32).copy()
        for _ in range(int(rng.integers(1, 6))):
            x0, x1 = np.sort(rng.integers(0, width, 2))
            y0, y1 = np.sort(rng.integers(0, height, 2))
            out[y0:y1 + 1, x0:x1 + 1] = rng.uniform(0, 1, 3) ** 1.5 * 255
        yy, xx = np.mgrid[:height, :width].astype(np.float32)
        gx, gy = rng.uniform(-0.4, 0.4, 2)
        out *= (1 + gx * (xx / width - 0.5) + gy * (yy / height - 0.5))[..., None]
    elif kind < 0.85:  # smooth gradient between two colours
        t = (_noise_field(height, width, rng, 2)[..., None] + 1) / 2
        out = base * t + (rng.uniform(0, 1, 3) ** 1.5 * 255) * (1 - t)
    else:  # saturated blobs
        cells = int(rng.integers(2, 9))
        coarse = rng.uniform(0, 255, (cells, cells, 3)).astype(np.float32)
        out = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    return out.astype(np.float32) + rng.normal(0, rng.uniform(1, 8), (height, width, 3)).astype(np.float32)


def _fresh_background(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A newly drawn background (H, W, 3) float32 0..255: a tinted, randomly scaled crop of a pool photo
    (half the time) or a procedural background."""
    pool = augmentation_backgrounds()
    if pool and rng.random() < 0.5:
        photo = pool[int(rng.integers(len(pool)))]
        ph, pw = photo.shape[:2]
        scale = rng.uniform(0.1, 1.0)
        ch, cw = max(4, int(ph * scale)), max(4, int(pw * scale))
        ch, cw = min(ch, ph), min(cw, pw)
        y0, x0 = int(rng.integers(0, ph - ch + 1)), int(rng.integers(0, pw - cw + 1))
        out = cv2.resize(photo[y0:y0 + ch, x0:x0 + cw], (width, height), interpolation=cv2.INTER_AREA)
        out = out.astype(np.float32)
        if rng.random() < 0.3:  # grey photographs: the hand must be found by shape, not by colour alone
            out = np.repeat(out.mean(axis=2, keepdims=True), 3, axis=2)
        return out * rng.uniform(0.4, 1.2, 3)
    return procedural_background(height, width, rng)


BANK_SIDE_PX = 192
BANK_SIZE = 512


@lru_cache(maxsize=1)
def background_bank() -> np.ndarray:
    """(BANK_SIZE, 128, 128, 3) uint8 backgrounds drawn once per process (fixed seed): drawing a fresh
    procedural texture per view cost more than the network's forward pass; windows of a bank are cheap."""
    rng = np.random.default_rng(20190)
    return np.stack([np.clip(_fresh_background(BANK_SIDE_PX, BANK_SIDE_PX, rng), 0, 255).astype(np.uint8)
                     for _ in range(BANK_SIZE)])


def random_background(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A random background (H, W, 3) uint8: a random window of a bank image (random scale, flip, tint)."""
    bank = background_bank()
    image = bank[int(rng.integers(len(bank)))]
    side = int(rng.integers(BANK_SIDE_PX // 3, BANK_SIDE_PX + 1))
    y0, x0 = (int(v) for v in rng.integers(0, BANK_SIDE_PX - side + 1, 2))
    window = image[y0:y0 + side, x0:x0 + side]
    if rng.random() < 0.5:
        window = window[:, ::-1]
    if rng.random() < 0.5:
        window = window.transpose(1, 0, 2)
    out = cv2.resize(np.ascontiguousarray(window), (width, height), interpolation=cv2.INTER_LINEAR)
    return np.clip(out.astype(np.float32) * rng.uniform(0.7, 1.3, 3), 0, 255).astype(np.uint8)


def despill(image: np.ndarray) -> np.ndarray:
    """Remove green-screen spill: green limited to the mean of red and blue ((H, W, 3) uint8 RGB)."""
    out = image.copy()
    limit = ((image[..., 0].astype(np.uint16) + image[..., 2]) // 2).astype(np.uint8)
    np.minimum(out[..., 1], limit, out=out[..., 1])
    return out


def recolor_foreground(image: np.ndarray, rng: np.random.Generator, amount: float = 1.0) -> np.ndarray:
    """Random skin-tone change of a despilled foreground ((H, W, 3) uint8 -> float32 0..255): brightness
    (log-uniform 0.25..1.5, covering very dark to very pale skin), saturation (0.2..1.3) and a mild tint."""
    img = image.astype(np.float32)
    if amount <= 0:
        return img
    gray = img.mean(axis=-1, keepdims=True)
    saturation = rng.uniform(1 - 0.8 * amount, 1 + 0.3 * amount)
    gain = np.exp(rng.uniform(np.log(0.25) * amount, np.log(1.5) * amount))
    tint = 1 + rng.uniform(-0.12, 0.12, 3) * amount
    return (gray + saturation * (img - gray)) * gain * tint


def composite(foreground: np.ndarray, alpha: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The supplementary's Cut&Paste, once: `foreground` ((H, W, 3) RGB, 0..255, any dtype) over a random
    background of the pool (`random_background`), with `alpha` ((H, W) float 0..1) softened by one pixel
    (3 x 3 Gaussian) as the blend weight. Returns (H, W, 3) uint8."""
    a = cv2.GaussianBlur(np.asarray(alpha, np.float32), (3, 3), 0)[..., None]
    background = random_background(foreground.shape[0], foreground.shape[1], rng).astype(np.float32)
    return np.clip(foreground.astype(np.float32) * a + background * (1 - a), 0, 255).astype(np.uint8)


def cut_and_paste(image: np.ndarray, alpha: np.ndarray, rng: np.random.Generator,
                  recolor: float = 1.0) -> np.ndarray:
    """Put the foreground of a green-screen image (alpha (H, W) uint8 0..255) on a random background:
    despilled, recoloured (`recolor` = strength, 0 = keep colours), composited with a softened alpha."""
    foreground = recolor_foreground(despill(image), rng, recolor)
    return composite(foreground, alpha.astype(np.float32) / 255.0, rng)


def color_jitter(image: np.ndarray, amount: float, rng: np.random.Generator) -> np.ndarray:
    """Random per-channel gain and a common offset, amplitude `amount` (fraction), and mild noise."""
    if amount <= 0:
        return image
    gain = 1 + rng.uniform(-amount, amount, 3)
    offset = rng.uniform(-amount, amount) * 60
    out = image.astype(np.float32)
    if rng.random() < 0.1:  # now and then a grey image (low-saturation skin in grey surroundings)
        out = np.repeat(out.mean(axis=2, keepdims=True), 3, axis=2)
    out = out * gain + offset
    if rng.random() < 0.5:
        out += rng.normal(0, rng.uniform(1, 6), out.shape).astype(np.float32)
    return np.clip(out, 0, 255).astype(np.uint8)


# --- MVNet dataset -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MVNetDataset:
    """Hand crops of M frames with 3D keypoint labels.

    Attributes:
        crops: (M, C, S, S, 3) uint8 RGB crops around centers_world.
        alphas: (M, C, S, S) uint8 foreground (chroma-key) masks for cut-and-paste; all 0 without one.
        has_alpha: (M,) bool, the frame is a green-screen frame with chroma-key masks.
        K_crop: (M, C, 3, 3) float32 crop intrinsics, pixels.
        view_valid: (M, C) bool.
        centers_world: (M, 3) float32 crop centres, metres, world frame.
        keypoints_3d: (M, K, 3) float32 labels, metres, world frame (NaN rows = unlabelled keypoints).
        cameras: the rig (C cameras).
        sample_ids: M ids ("<sequence>/<frame>").
        crop_px, crop_radius_m: how the crops were made.
        detector_px: (M, C, K, 2) float32 the detector's keypoints in pixels of the full images (NaN where a
            view found none), or None for a paper-only configuration.
        detector_scores: (M, C, K) float32 their map weights (detections.FrameDetections.scores), or None.
        detector_offsets: the learned keypoint offsets the detections were corrected with (FrameDetections.corrected),
            or None.
        detector_world: (M, K, 3) float64 the detector's lifted keypoints (corrected as detector_px), metres, world
            frame, NaN where not lifted; None for a paper-only configuration. Prediction's readout window
            (MVNetConfig.detector_window_m) is around them.
    """

    crops: np.ndarray
    alphas: np.ndarray
    has_alpha: np.ndarray
    K_crop: np.ndarray
    view_valid: np.ndarray
    centers_world: np.ndarray
    keypoints_3d: np.ndarray
    cameras: tuple[Camera, ...]
    sample_ids: tuple[str, ...]
    crop_px: int
    crop_radius_m: float
    detector_px: np.ndarray | None = None
    detector_scores: np.ndarray | None = None
    detector_offsets: KeypointOffsets | None = None
    detector_world: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.sample_ids)

    def subset(self, indices: Sequence[int] | np.ndarray) -> MVNetDataset:
        idx = np.asarray(indices, dtype=int)
        return MVNetDataset(self.crops[idx], self.alphas[idx], self.has_alpha[idx], self.K_crop[idx],
                            self.view_valid[idx], self.centers_world[idx], self.keypoints_3d[idx], self.cameras,
                            tuple(self.sample_ids[i] for i in idx), self.crop_px, self.crop_radius_m,
                            None if self.detector_px is None else self.detector_px[idx],
                            None if self.detector_scores is None else self.detector_scores[idx],
                            self.detector_offsets,
                            None if self.detector_world is None else self.detector_world[idx])


def hand_center_from_labels(masks: Sequence[np.ndarray] | None, keypoints_3d: np.ndarray,
                            cameras: Sequence[Camera]) -> np.ndarray:
    """The training crop centre: triangulated box centres of the label masks (as at prediction time),
    falling back to the mean keypoint. Returns (3,) metres, world frame."""
    if masks is not None:
        try:
            return localise_hand(masks, cameras).center_world
        except LocalisationError:
            pass
    return np.nanmean(keypoints_3d, axis=0)


def build_mvnet_dataset(capture: Capture, frames: Sequence[FrameRef], config: MVNetConfig, *,
                        keypoints_3d: np.ndarray | None = None,
                        hand_masks: Sequence[Mapping[str, np.ndarray] | None] | None = None,
                        detections: Sequence[FrameDetections] | None = None,
                        detection_cache: DetectionCache | None = None,
                        detector_offsets: KeypointOffsets | None = None,
                        progress: Callable[[int], None] | None = None) -> MVNetDataset:
    """Crops and labels of `frames`.

    Args:
        capture: the capture the frames belong to.
        frames: the labelled frames.
        config: crop size and radius.
        keypoints_3d: (M, K, 3) labels, metres (e.g. accepted MANO fits); default: the frames' ground truth.
        hand_masks: per frame, camera name -> (H, W) bool hand mask (e.g. the accepted fits' model masks), or
            None; the crops are centred on their triangulated blob centroids, as prediction crops are on
            HandSegNet's masks. Default: the ground-truth hand masks where the frames have some.
        detections: for a detector-backed configuration (heatmap_source="detector"), the frames' detections;
            default: detected here (detections.detect_frames with the chroma-key masks, through
            `detection_cache` when given: a frame is detected once, not per training step or round).
        detector_offsets: learned keypoint offsets to correct the detections with (learn_detector_offsets), as a
            configuration with detector_offsets=True trains and predicts; None: as detected.
        progress: called with 1 per frame done.
    Returns:
        MVNetDataset (crop centres from the hand masks; the mean keypoint where a frame has none or they
        cannot be triangulated; detector-backed: the detector's lifted keypoints' robust centroid where it
        lifted enough of them, as at prediction time).
    Raises:
        DetectorUnavailableError: detector-backed, no detections given and the model files are missing.
    """
    if hand_masks is not None and len(hand_masks) != len(frames):
        raise ValueError(f"hand_masks has {len(hand_masks)} entries for {len(frames)} frames")
    if keypoints_3d is not None and len(keypoints_3d) != len(frames):
        raise ValueError(f"keypoints_3d has {len(keypoints_3d)} entries for {len(frames)} frames")
    if detections is not None and len(detections) != len(frames):
        raise ValueError(f"detections has {len(detections)} entries for {len(frames)} frames")
    cameras = capture.cameras
    if config.heatmap_source == "detector" and detections is None:
        detections = detect_frames(frames, cameras, handedness=capture.hand_model.side, cache=detection_cache)
    if detections is not None and any(d.keypoints_px.shape[0] != len(cameras) for d in detections):
        raise ValueError(f"detections must have one entry per camera ({len(cameras)})")
    M, C, S = len(frames), len(cameras), config.crop_px
    crops = np.zeros((M, C, S, S, 3), np.uint8)
    alphas = np.zeros((M, C, S, S), np.uint8)
    has_alpha = np.zeros(M, bool)
    K_crop = np.zeros((M, C, 3, 3), np.float32)
    valid = np.zeros((M, C), bool)
    centers = np.zeros((M, 3), np.float32)
    labels = np.zeros((M, 21, 3), np.float32)
    for m, frame in enumerate(frames):
        images = load_frame_images(frame, cameras)
        gt = load_ground_truth(frame) if frame.ground_truth_path is not None else None
        if keypoints_3d is not None:
            labels[m] = keypoints_3d[m]
        elif gt is not None:
            labels[m] = gt.keypoints_3d
        else:
            raise ValueError(f"frame {frame_id(frame)} has no ground truth; pass keypoints_3d")
        if hand_masks is not None:
            given = hand_masks[m]
            if given is not None and any(c.name not in given for c in cameras):
                raise ValueError(f"hand_masks of frame {frame_id(frame)} lack camera(s) "
                                 f"{[c.name for c in cameras if c.name not in given]}")
            masks_m = [np.asarray(given[c.name], bool) for c in cameras] if given is not None else None
        else:
            masks_m = [gt.hand_masks[c.name] for c in cameras] if gt is not None and gt.hand_masks else None
        detected_center = detections[m].center_world() if detections is not None else None
        centers[m] = detected_center if detected_center is not None else \
            hand_center_from_labels(masks_m, labels[m], cameras)
        chroma = load_frame_masks(frame)
        masks = [chroma.get(c.name) for c in cameras] if chroma else None
        has_alpha[m] = bool(chroma)
        crops[m], K_crop[m], valid[m], mask_crops = crop_views([images[c.name] for c in cameras], cameras,
                                                               centers[m], S, config.crop_radius_m, masks)
        if mask_crops is not None:
            alphas[m] = mask_crops
        if progress:
            progress(1)
    det_px, det_scores, det_world = None, None, None
    if detections is not None and detector_offsets is not None:
        # after the crop centres, which stay the uncorrected lift's as at prediction time (predict_frames)
        detections = [d.corrected(detector_offsets, cameras) for d in detections]
    if detections is not None:
        det_px, det_scores = stack_detections(detections) if M else \
            (np.zeros((0, C, 21, 2), np.float32), np.zeros((0, C, 21), np.float32))
        det_world = np.stack([d.points_world for d in detections]) if M else np.zeros((0, 21, 3))
    return MVNetDataset(crops, alphas, has_alpha, K_crop, valid, centers, labels, tuple(cameras),
                        tuple(frame_id(f) for f in frames), S, config.crop_radius_m, det_px, det_scores,
                        detector_offsets if detections is not None else None, det_world)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random 3D rotation matrix (3, 3) (from a random unit quaternion)."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def crop_affine(crop_px: int, angle_rad: float, scale: float, shift_px: np.ndarray) -> np.ndarray:
    """(3, 3) map of crop pixels onto themselves: rotation by `angle_rad` and scaling about the crop centre,
    then a shift (pixel-centre convention)."""
    c = (crop_px - 1) / 2
    cos, sin = scale * np.cos(angle_rad), scale * np.sin(angle_rad)
    return np.array([[cos, -sin, c - cos * c + sin * c + shift_px[0]],
                     [sin, cos, c - sin * c - cos * c + shift_px[1]], [0, 0, 1.0]])


def augment_mvnet_batch(dataset: MVNetDataset, indices: np.ndarray, config: MVNetConfig,
                        rng: np.random.Generator, augment: bool = True) -> dict[str, np.ndarray]:
    """One training batch.

    Augmentation (config): per view a random in-plane rotation / scale / shift of the crop (its intrinsics
    follow: K' = A K, so the geometry stays exact), cut-and-paste onto a new background with a new skin
    tone, colour jitter; per frame a random subset of `train_views` views, a jittered grid centre and,
    with `grid_rotation`, a random orientation of the voxel grid (the 3D network then sees hands in every
    orientation; labels rotate with it).

    Returns:
        crops (B, C', S, S, 3) uint8, K_crop (B, C', 3, 3), view_valid (B, C'), view_index (B, C') int (which
        camera each view is), centers_world (B, 3), grid_rotation (B, 3, 3) (voxel axes in the world),
        keypoints_3d (B, K, 3); with the dataset's detections also detector_px (B, C', K, 2) float32 in the
        (augmented) crops' pixels and detector_scores (B, C', K).
    """
    indices = np.asarray(indices)
    B, C = len(indices), dataset.crops.shape[1]
    views = C if not augment or config.train_views <= 0 else min(C, config.train_views)
    view_index = np.stack([np.sort(rng.choice(C, views, replace=False)) if views < C else np.arange(C)
                           for _ in range(B)])
    crops = dataset.crops[indices[:, None], view_index].copy()
    K_crop = dataset.K_crop[indices[:, None], view_index].astype(np.float64)
    centers = dataset.centers_world[indices].astype(np.float64).copy()
    rotation = np.repeat(np.eye(3)[None], B, axis=0)
    S = dataset.crop_px
    if augment:
        for b, m in enumerate(indices):
            for v, c in enumerate(view_index[b]):
                crop, alpha = crops[b, v], dataset.alphas[m, c]
                if config.crop_rotation_deg > 0 or config.crop_scale > 0:
                    A = crop_affine(S, np.deg2rad(rng.uniform(-1, 1) * config.crop_rotation_deg),
                                    float(np.exp(rng.uniform(-1, 1) * config.crop_scale)), rng.normal(0, 0.03 * S, 2))
                    crop = cv2.warpAffine(crop, A[:2], (S, S), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
                    alpha = cv2.warpAffine(alpha, A[:2], (S, S), flags=cv2.INTER_LINEAR,
                                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                    K_crop[b, v] = A @ K_crop[b, v]
                if dataset.has_alpha[m] and rng.random() < config.cut_paste_prob:
                    crop = cut_and_paste(crop, alpha, rng, config.recolor)
                crops[b, v] = color_jitter(crop, config.color_jitter, rng)
            if config.grid_rotation:
                rotation[b] = random_rotation(rng)
        centers += rng.normal(0, config.center_jitter_m, centers.shape) if config.center_jitter_m > 0 else 0
    batch = {"crops": crops, "K_crop": K_crop.astype(np.float32),
             "view_valid": dataset.view_valid[indices[:, None], view_index], "view_index": view_index,
             "centers_world": centers.astype(np.float32), "grid_rotation": rotation.astype(np.float32),
             "keypoints_3d": dataset.keypoints_3d[indices]}
    if dataset.detector_px is not None and dataset.detector_scores is not None:
        K_cams = np.stack([np.asarray(c.K, np.float64) for c in dataset.cameras])[view_index]  # (B, C', 3, 3)
        batch["detector_px"] = image_to_crop_px(dataset.detector_px[indices[:, None], view_index], K_crop,
                                                K_cams).astype(np.float32)
        batch["detector_scores"] = dataset.detector_scores[indices[:, None], view_index]
    return batch


# --- HandSegNet dataset ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HandSegDataset:
    """Views of labelled frames with hand masks.

    Attributes:
        images: M views (H, W, 3) uint8 RGB (sizes may differ between cameras).
        targets: M (H, W) bool hand masks (accepted samples' masks).
        alphas: M (H, W) bool foreground (chroma-key) masks for cut-and-paste, or None.
        camera_index: (M,) int, index of each view's camera in `cameras`.
        centers_world: (M, 3) the frame's hand centre, metres, world frame.
        cameras: the rig.
        sample_ids: M ids ("<sequence>/<frame>/<camera>").
    """

    images: tuple[np.ndarray, ...]
    targets: tuple[np.ndarray, ...]
    alphas: tuple[np.ndarray | None, ...]
    camera_index: np.ndarray
    centers_world: np.ndarray
    cameras: tuple[Camera, ...]
    sample_ids: tuple[str, ...]

    def __post_init__(self) -> None:
        M = len(self.images)
        if not (len(self.targets) == len(self.alphas) == len(self.sample_ids) == len(self.camera_index)
                == len(self.centers_world) == M):
            raise ValueError("images, targets, alphas, camera_index, centers_world and sample_ids differ in length")
        for image, target, c in zip(self.images, self.targets, self.camera_index, strict=True):
            cam = self.cameras[int(c)]
            if image.shape != (cam.height, cam.width, 3) or target.shape != image.shape[:2]:
                raise ValueError(f"image {image.shape} / mask {target.shape} do not match camera {cam.name} "
                                 f"({cam.height}, {cam.width})")

    def __len__(self) -> int:
        return len(self.images)


def build_handseg_dataset(capture: Capture, frames: Sequence[FrameRef], *,
                          hand_masks: Sequence[dict[str, np.ndarray]] | None = None,
                          progress: Callable[[int], None] | None = None) -> HandSegDataset:
    """All views of `frames` with their hand masks (default: ground truth) and chroma-key masks."""
    cameras = capture.cameras
    images, targets, alphas, cam_index, centers, ids = [], [], [], [], [], []
    for m, frame in enumerate(frames):
        views = load_frame_images(frame, cameras)
        gt = load_ground_truth(frame) if hand_masks is None else None
        masks = hand_masks[m] if hand_masks is not None else gt.hand_masks
        ordered = [np.asarray(masks[c.name], bool) for c in cameras]
        fallback = gt.keypoints_3d if gt is not None else np.full((1, 3), np.nan)
        center = hand_center_from_labels(ordered, fallback, cameras)
        if not np.isfinite(center).all():
            log.warning("frame %s: no hand to localise, left out of the HandSegNet set", frame_id(frame))
            continue
        chroma = load_frame_masks(frame)
        for c, cam in enumerate(cameras):
            images.append(views[cam.name])
            targets.append(ordered[c])
            alphas.append(chroma.get(cam.name))
            cam_index.append(c)
            centers.append(center)
            ids.append(f"{frame_id(frame)}/{cam.name}")
        if progress:
            progress(1)
    return HandSegDataset(tuple(images), tuple(targets), tuple(alphas), np.asarray(cam_index, int),
                          np.asarray(centers, np.float64).reshape(-1, 3), tuple(cameras), tuple(ids))


def warp_crop(image: np.ndarray, A: np.ndarray, crop_px: int, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Resample an image (H, W[, 3]) into a crop through the affine map A (3, 3) image -> crop pixels."""
    if A[0, 0] < 0.7 and image.dtype == np.uint8 and image.ndim == 3:
        image = cv2.GaussianBlur(image, (0, 0), 0.45 / A[0, 0])
    return cv2.warpAffine(image, A[:2], (crop_px, crop_px), flags=interpolation, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=0)


def sample_handseg_batch(dataset: HandSegDataset, config: HandSegNetConfig, rng: np.random.Generator,
                         augment: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Random training crops at the fine or a coarser scale: images (B, S, S, 3) uint8, targets (B, S, S)
    float32 in [0, 1]."""
    S, B = config.crop_px, config.batch_size
    out_img = np.zeros((B, S, S, 3), np.uint8)
    out_tgt = np.zeros((B, S, S), np.float32)
    lo, hi = np.log(config.crop_radius_m), np.log(config.coarse_radius_m * 1.1)
    for b in range(B):
        m = int(rng.integers(len(dataset)))
        cam = dataset.cameras[int(dataset.camera_index[m])]
        if rng.random() < config.fine_prob:
            radius = config.crop_radius_m * rng.uniform(0.85, 1.15)
        else:
            radius = float(np.exp(rng.uniform(lo, hi)))
        center = dataset.centers_world[m] + (rng.normal(0, config.center_jitter * radius, 3) if augment else 0)
        A, ok = crop_transform(cam, center, S, radius)
        if not ok:
            continue
        image = warp_crop(dataset.images[m], A, S)
        target = warp_crop(dataset.targets[m].astype(np.float32), A, S)
        alpha = dataset.alphas[m]
        if augment:
            if alpha is not None and rng.random() < config.cut_paste_prob:
                image = cut_and_paste(image, warp_crop(alpha.astype(np.uint8) * 255, A, S), rng, config.recolor)
            image = color_jitter(image, config.color_jitter, rng)
            if rng.random() < 0.5:
                image, target = image[:, ::-1], target[:, ::-1]
        out_img[b], out_tgt[b] = image, target
    return out_img, out_tgt
