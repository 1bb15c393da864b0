"""FreiHAND's dataset layout, written from accepted fits and read back.

```
OUT/
  training_K.json  training_mano.json  training_xyz.json  training_scale.json  training_verts.json
  evaluation_K.json  ... (the same five for the evaluation split)
  training/rgb/%08d.jpg  training/mask/%08d.jpg  evaluation/rgb/%08d.jpg  evaluation/mask/%08d.jpg
  meshes/<sample id>.ply|.obj      fitted mesh per multi-view sample, world frame, metres
  handloop_export.json             manifest: hand model, per FreiHAND index its sample, camera, extrinsics,
                                   side ("right"/"left": FreiHAND's files have no side field)
  README.txt                       which hand model made the labels
```

One FreiHAND sample per view, as FreiHAND has: index i of a split is (sample, camera) in sample order,
cameras in calibration order. Per index, as FreiHAND defines them (camera frame, metres):
- K: (3, 3) intrinsics. Images are undistorted to this K (our cameras have lens distortion; FreiHAND's
  projection is `K @ xyz`), masks rendered with it.
- xyz: (21, 3) keypoints in the camera frame; verts: (V, 3) the fitted mesh in the camera frame.
- scale: metric length of the reference bone, middle finger MCP -> PIP (keypoints 9 -> 10).
- mano: [[61]] = pose 48 (global rotation in the camera frame 3, articulation 45 relative to the model's
  `hands_mean`, i.e. MANO's `flat_hand_mean=False` convention FreiHAND uses), shape 10, uv_root 2 (the
  projection of keypoint 9, pixels), and the orthographic scale focal / depth of keypoint 9 (FreiHAND's
  `recover_root`: xyz_root = [(uv - pp), focal] / scale).
- rgb: the image; `training/rgb` holds FreiHAND-style versions: index i + N * v is version v of training
  sample i (v = 0 the original, v >= 1 Cut&Paste composites onto the background pool of
  workers/nets/data.py through the sample's foreground mask), N the number of training samples.
- mask: the fitted hand model's silhouette (hand only, cut at the wrist by the model itself).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from workers.evaluation.freihand_files import EvaluationInputError, _point_array, load_json
from workers.export.meshes import MESH_FORMATS, write_mesh
from workers.export.records import SampleRecord, ViewRecord
from workers.geometry.camera import Camera
from workers.geometry.rotation import axis_angle_to_matrix
from workers.handmodel.arrays import HandModelArrays
from workers.handmodel.loading import STAND_IN_NOTICE
from workers.handmodel.params import HandParams
from workers.handmodel.posed import posed_mesh
from workers.nets.data import composite
from workers.rendering.rasterizer import model_mask

log = logging.getLogger(__name__)

SPLITS = {"train": "training", "evaluation": "evaluation"}  # our split name -> FreiHAND's set name
MANIFEST = "handloop_export.json"
ROOT_KEYPOINT = 9  # middle finger MCP: FreiHAND's root for uv_root and the reference bone
REFERENCE_BONE = (9, 10)
KEYPOINT_TOLERANCE_M = 0.001  # stored fit keypoints vs the hand model's, before we trust the model


class ExportError(ValueError):
    """An export cannot be made as asked; the message says what is wrong."""


@dataclass(frozen=True)
class ExportOptions:
    """Attributes:
        composites: Cut&Paste versions per green-screen training image (0 = originals only), 0..8.
        mesh_formats: mesh files per fitted sample: any of "ply", "obj" (empty: none).
        jpeg_quality: JPEG quality of rgb/ and mask/ images, 50..100.
        seed: seeds the backgrounds of the composites.
        force: replace a non-empty output folder.
    """

    composites: int = 0
    mesh_formats: tuple[str, ...] = ("ply",)
    jpeg_quality: int = 95
    seed: int = 0
    force: bool = False

    def __post_init__(self) -> None:
        if not 0 <= self.composites <= 8:
            raise ExportError(f"composites must be in 0..8, not {self.composites}")
        unknown = set(self.mesh_formats) - set(MESH_FORMATS)
        if unknown:
            raise ExportError(f"mesh formats must be among {MESH_FORMATS}, not {sorted(unknown)}")
        if not 50 <= self.jpeg_quality <= 100:
            raise ExportError(f"jpeg_quality must be in 50..100, not {self.jpeg_quality}")


@dataclass(frozen=True)
class ExportSummary:
    """What was written: FreiHAND samples (views) and images per set, multi-view samples, meshes."""

    out_dir: Path
    hand_model: str
    is_mano: bool
    samples: dict[str, int] = field(default_factory=dict)
    images: dict[str, int] = field(default_factory=dict)
    multi_view_samples: int = 0
    meshes: int = 0


# --- the hand model --------------------------------------------------------------------------------------


def model_matches(model_file: str, arrays: HandModelArrays) -> bool:
    """Whether a fit's recorded model name refers to `arrays` (names as fits record them: the model's name,
    a path to a MANO pickle, or "builtin")."""
    name = Path(model_file).name if model_file else ""
    if arrays.is_mano:
        return name == arrays.name or name.upper().startswith("MANO")
    return "builtin" in model_file.lower() or name == arrays.name


def hand_model_notice(arrays: HandModelArrays) -> str:
    if arrays.is_mano:
        return f"Labels made with the MANO model ({arrays.name})."
    return f"Labels made with {arrays.name}, not MANO. {STAND_IN_NOTICE}"


def focal_and_principal_point(K: np.ndarray) -> tuple[float, np.ndarray]:
    """FreiHAND's `get_focal_pp`: focal = mean of fx and fy, principal point (2,)."""
    return 0.5 * (float(K[0, 0]) + float(K[1, 1])), np.asarray(K[:2, 2], np.float64)


def backproject_root(uv_root: np.ndarray, scale: float, K: np.ndarray) -> np.ndarray:
    """FreiHAND's `recover_root`: the root keypoint (3,) in the camera frame from its pixel and scale."""
    focal, pp = focal_and_principal_point(K)
    return np.concatenate([np.asarray(uv_root, np.float64) - pp, [focal]]) / scale


def freihand_theta(params: HandParams, view: ViewRecord, xyz_cam: np.ndarray, arrays: HandModelArrays) -> np.ndarray:
    """(61,) FreiHAND parameters of one view from our parameters and the view's camera-frame keypoints."""
    global_cam = Rotation.from_matrix(view.R @ axis_angle_to_matrix(params.global_orient)).as_rotvec()
    articulation = params.pose - arrays.hands_mean
    root = xyz_cam[ROOT_KEYPOINT]
    if root[2] <= 0:
        raise ExportError(f"camera {view.name}: the hand's root keypoint is behind the camera")
    uv = (view.K @ root)[:2] / root[2]
    focal, _ = focal_and_principal_point(view.K)
    return np.concatenate([global_cam, articulation, params.betas, uv, [focal / root[2]]])


# --- images ------------------------------------------------------------------------------------------------


def _decode(data: bytes, flags: int, what: str) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None:
        raise ExportError(f"{what}: cannot be decoded")
    return image


def _undistort(image: np.ndarray, view: ViewRecord, nearest: bool = False) -> np.ndarray:
    if not np.any(view.dist):
        return image
    map_x, map_y = cv2.initUndistortRectifyMap(view.K, view.dist, None, view.K, (view.width, view.height),
                                               cv2.CV_32FC1)
    return cv2.remap(image, map_x, map_y, cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT)


def cut_and_paste(image_rgb: np.ndarray, foreground: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The supplementary's Cut&Paste: the image blended onto a random background of the networks' pool
    (workers/nets/data.py) with the foreground mask as alpha, softened by one pixel; the foreground keeps
    its colours (the training augmentation of workers/nets may recolour it; a dataset must not)."""
    return composite(image_rgb, foreground, rng)


def _pinhole(view: ViewRecord) -> Camera:
    """The view's camera without distortion (the export's images are undistorted)."""
    return Camera(view.name, view.width, view.height, view.K, np.zeros(5), view.R, view.t)


# --- writing -----------------------------------------------------------------------------------------------


def _prepare_out_dir(out_dir: Path, force: bool) -> Path:
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ExportError(f"{out_dir} exists and is not a folder")
    if out_dir.exists() and any(out_dir.iterdir()) and not force:
        raise ExportError(f"{out_dir} is not empty; choose another folder or pass --force to replace it")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    return out_dir.parent / f".{out_dir.name}.partial-{uuid.uuid4().hex[:8]}"


def _dump(path: Path, value: Any) -> None:
    path.write_text(json.dumps(value))


def write_freihand(samples: Sequence[SampleRecord], out_dir: Path, read_bytes: Callable[[str], bytes],
                   arrays: HandModelArrays, options: ExportOptions | None = None,
                   progress: Callable[[int], None] | None = None, *,
                   other_side: HandModelArrays | None = None,
                   label_quality: dict[str, Any] | None = None) -> ExportSummary:
    """Write `samples` in FreiHAND's layout to `out_dir`.

    Args:
        samples: accepted samples with their fits (backend.services.exports.export.export_records).
        out_dir: the folder to create (must be absent or empty unless options.force).
        read_bytes: storage key -> file bytes (images and masks).
        arrays: the hand model that made the fits (checked against each fit's keypoints), of its side.
        progress: called with 1 after each multi-view sample.
        other_side: the other side's hand model, needed when samples of that side are exported (a left hand's
            fit poses the left model). FreiHAND's label files have no side: each sample's is in the
            manifest (handloop_export.json, sets.<set>.samples[i].side).
        label_quality: the labels' audit figures (services.review.label_audits.summary: per round and stream, audited,
            found wrong, the share and its Wilson 95 % interval), written as the manifest's "quality".
    Everything is written into a temporary sibling folder that replaces `out_dir` at the end: a failed
    export leaves nothing behind.
    """
    options = options or ExportOptions()
    if not samples:
        raise ExportError("nothing to export: no accepted samples")
    models = {arrays.side: arrays}
    if other_side is not None:
        models[other_side.side] = other_side
    for record in samples:
        if record.split not in SPLITS:
            raise ExportError(f"sample {record.sample_id}: unknown split {record.split!r}")
        if record.side not in models:
            raise ExportError(f"sample {record.sample_id} is a {record.side} hand, but the export was given only "
                              f"the {' and '.join(sorted(models))} hand model")
        if not model_matches(record.model_file, models[record.side]):
            raise ExportError(f"fit {record.fit_id} of sample {record.sample_id} was made with "
                              f"{record.model_file!r}, but the hand model loaded for the export is {arrays.name!r}; "
                              "set HANDLOOP_MANO_PATH to the model the fits used")
    tmp = _prepare_out_dir(out_dir, options.force)
    rng = np.random.default_rng(options.seed)
    quality = [cv2.IMWRITE_JPEG_QUALITY, options.jpeg_quality]
    labels: dict[str, dict[str, list]] = {s: {"K": [], "mano": [], "xyz": [], "scale": [], "verts": []}
                                          for s in SPLITS.values()}
    index: dict[str, list[dict]] = {s: [] for s in SPLITS.values()}
    counts = {s: sum(len(r.views) for r in samples if SPLITS[r.split] == s) for s in SPLITS.values()}
    images = dict.fromkeys(SPLITS.values(), 0)
    meshes = 0
    try:
        for set_name in SPLITS.values():
            (tmp / set_name / "rgb").mkdir(parents=True)
            (tmp / set_name / "mask").mkdir(parents=True)
        for record in samples:
            set_name = SPLITS[record.split]
            side_model = models[record.side]
            mesh = posed_mesh(side_model, record.hand_params)
            keypoints_model, vertices = mesh.keypoints, mesh.vertices
            gap = float(np.linalg.norm(keypoints_model - record.keypoints_m, axis=1).max())
            if gap > KEYPOINT_TOLERANCE_M:
                raise ExportError(f"fit {record.fit_id} of sample {record.sample_id}: its keypoints differ by "
                                  f"{gap * 1000:.1f} mm from those of {side_model.name} ({record.side}) posed "
                                  "with its parameters; "
                                  "the export's hand model is not the one that made the fit")
            mesh_files = []
            for fmt in options.mesh_formats:
                rel = f"meshes/{record.sample_id:08d}.{fmt}"
                write_mesh(tmp / rel, vertices, side_model.faces)
                mesh_files.append(rel)
                meshes += 1
            for view in record.views:
                i = len(labels[set_name]["K"])
                xyz = record.keypoints_m @ view.R.T + view.t
                verts = vertices @ view.R.T + view.t
                label = labels[set_name]
                label["K"].append(view.K.tolist())
                label["mano"].append([freihand_theta(record.hand_params, view, xyz, side_model).tolist()])
                label["xyz"].append(xyz.tolist())
                label["scale"].append(float(np.linalg.norm(xyz[REFERENCE_BONE[0]] - xyz[REFERENCE_BONE[1]])))
                label["verts"].append(verts.tolist())
                where = f"sample {record.sample_id} camera {view.name}"
                image = _undistort(_decode(read_bytes(view.image_key), cv2.IMREAD_COLOR, f"{where} image"), view)
                if image.shape[:2] != (view.height, view.width):
                    raise ExportError(f"{where}: image is {image.shape[1]}x{image.shape[0]}, the camera "
                                      f"{view.width}x{view.height}")
                cv2.imwrite(str(tmp / set_name / "rgb" / f"{i:08d}.jpg"), image, quality)
                silhouette = model_mask(vertices, side_model.faces, _pinhole(view))
                cv2.imwrite(str(tmp / set_name / "mask" / f"{i:08d}.jpg"),
                            np.where(silhouette, 255, 0).astype(np.uint8), quality)
                images[set_name] += 1
                composited = 0
                if options.composites and set_name == "training" and record.green_screen \
                        and view.foreground_mask_key is not None:
                    alpha = _undistort(_decode(read_bytes(view.foreground_mask_key), cv2.IMREAD_GRAYSCALE,
                                               f"{where} foreground mask"), view, nearest=True)
                    rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
                    for version in range(1, options.composites + 1):
                        composite = cut_and_paste(rgb, alpha >= 128, rng)
                        cv2.imwrite(str(tmp / set_name / "rgb" / f"{i + counts[set_name] * version:08d}.jpg"),
                                    cv2.cvtColor(composite, cv2.COLOR_RGB2BGR), quality)
                        images[set_name] += 1
                        composited += 1
                index[set_name].append({
                    "index": i, "sample_id": record.sample_id, "fit_id": record.fit_id, "sequence": record.sequence,
                    "frame_index": record.frame_index, "camera": view.name, "round": record.round_index,
                    "stream": record.stream, "fit_source": record.fit_source, "side": record.side,
                    "R": view.R.tolist(),
                    "t": view.t.tolist(), "dist": view.dist.tolist(), "composites": composited, "meshes": mesh_files,
                })
            if progress is not None:
                progress(1)
        for set_name, label in labels.items():
            for key, values in label.items():
                _dump(tmp / f"{set_name}_{key}.json", values)
        notice = hand_model_notice(arrays)
        manifest = {
            "format": "freihand", "generator": "handloop", "version": 1,
            "created_at": datetime.now(UTC).isoformat(timespec="seconds"),
            "hand_model": {"name": arrays.name, "is_mano": arrays.is_mano, "num_vertices": arrays.num_vertices,
                           "notice": notice, "sides": sorted({r.side for r in samples})},
            "units": "metres; keypoints and vertices in each view's camera frame; meshes/ in the world frame",
            "image_versions": ["original"] + [f"cut_and_paste_{v}" for v in range(1, options.composites + 1)],
            "sets": {s: {"count": len(index[s]), "images": images[s], "samples": index[s]} for s in index},
        }
        if label_quality is not None:
            manifest["quality"] = label_quality
        _dump(tmp / MANIFEST, manifest)
        (tmp / "README.txt").write_text(
            "FreiHAND-layout export written by handloop (see docs/evaluation.md in the handloop repository).\n"
            f"{notice}\n"
            f"training: {len(index['training'])} samples (one per view), evaluation: {len(index['evaluation'])}.\n")
        if out_dir.exists():
            shutil.rmtree(out_dir)
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    log.info("exported %d training and %d evaluation samples to %s", len(index["training"]),
             len(index["evaluation"]), out_dir)
    return ExportSummary(out_dir=Path(out_dir), hand_model=arrays.name, is_mano=arrays.is_mano,
                         samples={s: len(v) for s, v in index.items()}, images=images,
                         multi_view_samples=len(samples), meshes=meshes)


# --- reading back ------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FreiHANDSet:
    """One split of a FreiHAND-layout folder.

    Attributes:
        K: (N, 3, 3).  mano: (N, 61).  xyz: (N, 21, 3) metres, camera frame.  scale: (N,) metres.
        verts: (N, V, 3) metres, camera frame.  entries: the manifest's per-index records ([] without one).
    """

    K: np.ndarray
    mano: np.ndarray
    xyz: np.ndarray
    scale: np.ndarray
    verts: np.ndarray
    entries: list[dict]

    def __len__(self) -> int:
        return int(self.K.shape[0])

    def world_keypoints(self, i: int) -> np.ndarray:
        """(21, 3) keypoints of index i back in the world frame (needs the manifest's extrinsics)."""
        entry = self.entries[i]
        R, t = np.asarray(entry["R"]), np.asarray(entry["t"])
        return (self.xyz[i] - t) @ R


def read_freihand_set(folder: Path, set_name: str) -> FreiHANDSet:
    """Read the five label files of a split (and the manifest's entries when there is one)."""
    folder = Path(folder)
    where = {key: folder / f"{set_name}_{key}.json" for key in ("K", "mano", "xyz", "scale", "verts")}
    raw_k = load_json(where["K"])
    K = np.asarray(raw_k, np.float64) if raw_k else np.zeros((0, 3, 3))
    if K.ndim != 3 or K.shape[1:] != (3, 3) or not np.isfinite(K).all():
        raise EvaluationInputError(f"{where['K']}: expected a list of finite 3x3 matrices")
    raw_mano = load_json(where["mano"])
    mano = np.asarray(raw_mano, np.float64).reshape(len(raw_mano), -1) if raw_mano else np.zeros((0, 61))
    if mano.shape[1:] != (61,) or not np.isfinite(mano).all():
        raise EvaluationInputError(f"{where['mano']}: expected [[61 finite numbers]] per sample")
    scale = np.asarray(load_json(where["scale"]), np.float64)
    xyz_raw, verts_raw = load_json(where["xyz"]), load_json(where["verts"])
    xyz = _point_array(xyz_raw, str(where["xyz"]), 21) if xyz_raw else np.zeros((0, 21, 3))
    verts = _point_array(verts_raw, str(where["verts"]), None) if verts_raw else np.zeros((0, 0, 3))
    sizes = {len(K), len(mano), len(xyz), len(scale), len(verts)}
    if len(sizes) != 1:
        raise EvaluationInputError(f"{folder}: the {set_name}_* files hold different sample counts")
    entries: list[dict] = []
    if (folder / MANIFEST).exists():
        entries = load_json(folder / MANIFEST)["sets"][set_name]["samples"]
    return FreiHANDSet(K=K, mano=mano, xyz=xyz, scale=scale, verts=verts, entries=entries)


def mesh_from_freihand(arrays: HandModelArrays, mano: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose the hand model from one FreiHAND parameter vector (61,) and K: (keypoints (21, 3), vertices
    (V, 3)), metres, camera frame; what FreiHAND's `pose_hand` computes with MANO."""
    mano = np.asarray(mano, np.float64).reshape(-1)
    pose, shape, uv_root, scale = mano[:48], mano[48:58], mano[58:60], float(mano[60])  # FreiHAND's layout
    params = HandParams(betas=shape, pose=pose[3:], global_orient=pose[:3], transl=np.zeros(3))
    mesh = posed_mesh(arrays, params, mean_pose=True)  # FreiHAND's articulation is relative to hands_mean
    shift = backproject_root(uv_root, scale, K) - mesh.keypoints[ROOT_KEYPOINT]
    return mesh.keypoints + shift, mesh.vertices + shift
