"""Read and validate a capture directory (docs/capture-format.md).

Every problem raises `CaptureError` with the offending file and field (or folder) in its message:
unknown or missing JSON keys, non-finite numbers, unknown ids, missing or extra camera folders,
missing frames, frame-count mismatches, images whose size differs from the calibration, and images
that cannot be read. `read_capture` checks every image's header (size and format, cheap); pixel data
is decoded, and checked again, by `load_frame_images`, and before an import by
`workers.capture.verify.verify_capture_files` (every file in full).
"""

from __future__ import annotations

import json
import math
import threading
import zipfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from workers.capture.chroma import ChromaKey
from workers.capture.schema import (
    CALIBRATION_FILE,
    CAPTURE_FILE,
    CAPTURE_KEYS_OPTIONAL,
    CAPTURE_KEYS_REQUIRED,
    FORMAT_NAME,
    FORMAT_VERSION,
    GROUND_TRUTH_DIR,
    GT_ARRAYS,
    GT_MASKS_DIR,
    HAND_MODEL_KEYS_OPTIONAL,
    HAND_MODEL_KEYS_REQUIRED,
    ID_PATTERN,
    IMAGE_FORMATS,
    IMAGES_DIR,
    MASKS_DIR,
    SEQUENCE_FILE,
    SEQUENCE_KEYS_OPTIONAL,
    SEQUENCE_KEYS_REQUIRED,
    SEQUENCES_DIR,
    SPLITS,
    SUBJECT_KEYS_OPTIONAL,
    SUBJECT_KEYS_REQUIRED,
    SUBJECTS_FILE,
    VERSION_2_CAPTURE_KEYS,
    VERSION_2_SEQUENCE_KEYS,
    Capture,
    CaptureError,
    FrameRef,
    GroundTruth,
    HandModelInfo,
    Sequence,
    Subject,
    frame_name,
)
from workers.geometry.camera import CalibrationError, Camera, load_calibration

# --- small validators: each names the file (`where`) and the field ---------------------------------


def _load_json(path: Path) -> Any:
    if not path.is_file():
        raise CaptureError(f"{path}: file not found")
    try:
        # NaN / Infinity parse (Python's json writes them) and are rejected field by field below.
        return json.loads(path.read_text())
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        raise CaptureError(f"{path}: not valid JSON ({exc})") from None


def _check_keys(obj: Any, required: frozenset[str], optional: frozenset[str], where: str) -> dict[str, Any]:
    if not isinstance(obj, dict):
        raise CaptureError(f"{where}: expected a JSON object, got {type(obj).__name__}")
    unknown = set(obj) - required - optional
    if unknown:
        raise CaptureError(f"{where}: unknown field(s) {sorted(unknown)}")
    missing = required - set(obj)
    if missing:
        raise CaptureError(f"{where}: missing field(s) {sorted(missing)}")
    return obj


def _typed(obj: dict[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    value = obj[key]
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind in (int, float, (int, float)):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if ok and not math.isfinite(value):
            raise CaptureError(f"{where}: field '{key}' is not a finite number")
        if ok and kind is int:
            ok = float(value).is_integer()
    else:
        ok = isinstance(value, kind)
    if not ok:
        name = kind.__name__ if isinstance(kind, type) else "number"
        raise CaptureError(f"{where}: field '{key}' must be {name}, got {value!r}")
    return int(value) if kind is int else value


def _check_id(value: Any, field_name: str, where: str) -> str:
    if not isinstance(value, str) or not ID_PATTERN.match(value):
        raise CaptureError(f"{where}: field '{field_name}' must be an id matching {ID_PATTERN.pattern}, "
                           f"got {value!r}")
    return value


def _visible_entries(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if not p.name.startswith("."))


# --- header, calibration, subjects ---------------------------------------------------------------


def _read_header(root: Path) -> tuple[str, bool, HandModelInfo]:
    path = root / CAPTURE_FILE
    where = str(path)
    data = _check_keys(_load_json(path), CAPTURE_KEYS_REQUIRED, CAPTURE_KEYS_OPTIONAL, where)
    if data["format"] != FORMAT_NAME:
        raise CaptureError(f"{where}: field 'format' must be {FORMAT_NAME!r}, got {data['format']!r}")
    version = _typed(data, "version", int, where)
    if version > FORMAT_VERSION or version < 1:
        raise CaptureError(f"{where}: field 'version' is {version}; this reader supports 1..{FORMAT_VERSION}")
    name = _typed(data, "name", str, where)
    synthetic = _typed(data, "synthetic", bool, where)
    if "description" in data:
        _typed(data, "description", str, where)
    if "generator" in data:
        _typed(data, "generator", dict, where)
    _check_version_2_keys(data, VERSION_2_CAPTURE_KEYS, version, where)
    model_where = f"{where}: hand_model"
    model = _check_keys(data["hand_model"], HAND_MODEL_KEYS_REQUIRED, HAND_MODEL_KEYS_OPTIONAL, model_where)
    side = _typed(model, "side", str, model_where)
    if side not in ("right", "left"):
        raise CaptureError(f"{model_where}: field 'side' must be 'right' or 'left', got {side!r}")
    num_vertices = None
    if "num_vertices" in model:
        num_vertices = _typed(model, "num_vertices", int, model_where)
        if num_vertices <= 0:
            raise CaptureError(f"{model_where}: field 'num_vertices' must be positive")
    info = HandModelInfo(
        name=_typed(model, "name", str, model_where),
        is_mano=_typed(model, "is_mano", bool, model_where),
        side=side,
        num_vertices=num_vertices,
        source_note=_typed(model, "source_note", str, model_where) if "source_note" in model else "",
    )
    return name, synthetic, info


def _check_version_2_keys(data: dict[str, Any], keys: frozenset[str], version: int, where: str) -> None:
    present = sorted(keys & set(data))
    if present and version < 2:
        raise CaptureError(f"{where}: field(s) {present} need capture.json 'version' 2, the file says {version}")


def _read_working_width(root: Path) -> int | None:
    """capture.json's optional 'working_width_px' (version 2), checked against nothing but its range."""
    path = root / CAPTURE_FILE
    data = _load_json(path)
    if "working_width_px" not in data:
        return None
    width = _typed(data, "working_width_px", int, str(path))
    if not 16 <= width <= 100_000:
        raise CaptureError(f"{path}: field 'working_width_px' must be in 16..100000, got {width}")
    return width


def _read_chroma_key(data: dict[str, Any], version: int, where: str) -> dict[str, Any] | None:
    _check_version_2_keys(data, VERSION_2_SEQUENCE_KEYS, version, where)
    if "chroma_key" not in data:
        return None

    try:
        return ChromaKey.from_dict(data["chroma_key"]).to_dict()
    except (TypeError, ValueError) as exc:
        raise CaptureError(f"{where}: field 'chroma_key': {exc}") from None


def _read_calibration(root: Path) -> tuple[Camera, ...]:
    try:
        cameras = load_calibration(root / CALIBRATION_FILE)
    except CalibrationError as exc:
        raise CaptureError(str(exc)) from None
    for cam in cameras:
        _check_id(cam.name, "name", f"{root / CALIBRATION_FILE}: camera {cam.name!r}")
    return tuple(cameras)


def _read_subjects(root: Path) -> dict[str, Subject]:
    path = root / SUBJECTS_FILE
    data = _check_keys(_load_json(path), frozenset({"subjects"}), frozenset(), str(path))
    if not isinstance(data["subjects"], list):
        raise CaptureError(f"{path}: field 'subjects' must be a list")
    subjects: dict[str, Subject] = {}
    for i, row in enumerate(data["subjects"]):
        where = f"{path}: subjects[{i}]"
        row = _check_keys(row, SUBJECT_KEYS_REQUIRED, SUBJECT_KEYS_OPTIONAL, where)
        sid = _check_id(row["id"], "id", where)
        if sid in subjects:
            raise CaptureError(f"{where}: field 'id' repeats subject {sid!r}")
        betas = None
        if row.get("betas") is not None:
            try:
                betas = np.asarray(row["betas"], dtype=np.float64)
            except (TypeError, ValueError):
                raise CaptureError(f"{where}: field 'betas' must be a list of 10 numbers") from None
            if betas.shape != (10,):
                raise CaptureError(f"{where}: field 'betas' must have 10 numbers, got shape {betas.shape}")
            if not np.all(np.isfinite(betas)):
                raise CaptureError(f"{where}: field 'betas' contains non-finite numbers")
        skin = row.get("skin_tone")
        if skin is not None and (not isinstance(skin, str) or len(skin) != 7 or skin[0] != "#"
                                 or any(c not in "0123456789abcdefABCDEF" for c in skin[1:])):
            raise CaptureError(f"{where}: field 'skin_tone' must be a hex colour like '#a07e56', got {skin!r}")
        for key in ("sex", "notes"):
            if row.get(key) is not None:
                _typed(row, key, str, where)
        subjects[sid] = Subject(id=sid, betas=betas, skin_tone=skin, sex=row.get("sex"),
                                notes=row.get("notes") or "")
    return subjects


# --- sequences -------------------------------------------------------------------------------------


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the image header, without decoding the pixels."""
    try:
        with Image.open(path) as img:
            return img.size
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise CaptureError(f"{path}: unreadable image ({exc.__class__.__name__}: {exc})") from None


def _per_camera_folders(parent: Path, cameras: tuple[Camera, ...], what: str) -> None:
    """Check that `parent` holds exactly one folder per camera."""
    names = {c.name for c in cameras}
    found = {p.name for p in _visible_entries(parent) if p.is_dir()}
    files = [p.name for p in _visible_entries(parent) if not p.is_dir()]
    if files:
        raise CaptureError(f"{parent}: unexpected file(s) {files} in {what} (expected one folder per camera)")
    missing, extra = sorted(names - found), sorted(found - names)
    if missing:
        raise CaptureError(f"{parent}: missing camera folder(s) {missing} in {what} "
                           f"(calibration has {sorted(names)})")
    if extra:
        raise CaptureError(f"{parent}: camera folder(s) {extra} in {what} are not in the calibration "
                           f"{sorted(names)}")


def _frame_files(folder: Path, ext: str, num_frames: int, what: str) -> list[Path]:
    """The files 000000.<ext> .. for every frame; missing or extra frame files raise."""
    expected = [folder / f"{frame_name(i)}.{ext}" for i in range(num_frames)]
    present = {p.name for p in _visible_entries(folder)}
    for path in expected:
        if path.name not in present:
            raise CaptureError(f"{path}: missing frame {int(path.stem)} of {what} "
                               f"(sequence.json 'num_frames' is {num_frames})")
    extra = sorted(present - {p.name for p in expected})
    if extra:
        raise CaptureError(f"{folder}: {len(extra)} file(s) beyond sequence.json 'num_frames' = {num_frames} "
                           f"or misnamed, e.g. {extra[0]!r}")
    return expected


def _read_sequence(seq_dir: Path, cameras: tuple[Camera, ...], subjects: dict[str, Subject],
                   check_images: bool, version: int = 1) -> Sequence:
    path = seq_dir / SEQUENCE_FILE
    where = str(path)
    data = _check_keys(_load_json(path), SEQUENCE_KEYS_REQUIRED, SEQUENCE_KEYS_OPTIONAL, where)
    seq_id = _check_id(data["id"], "id", where)
    if seq_id != seq_dir.name:
        raise CaptureError(f"{where}: field 'id' is {seq_id!r} but the folder is named {seq_dir.name!r}")
    subject = _typed(data, "subject", str, where)
    if subject not in subjects:
        raise CaptureError(f"{where}: field 'subject' is {subject!r}, not a subject of subjects.json "
                           f"{sorted(subjects)}")
    split = data["split"]
    if split not in SPLITS:
        raise CaptureError(f"{where}: field 'split' must be one of {SPLITS}, got {split!r}")
    fps = float(_typed(data, "fps", (int, float), where))
    if fps <= 0:
        raise CaptureError(f"{where}: field 'fps' must be positive, got {fps}")
    num_frames = _typed(data, "num_frames", int, where)
    if num_frames < 1:
        raise CaptureError(f"{where}: field 'num_frames' must be at least 1, got {num_frames}")
    image_format = data["image_format"]
    if image_format not in IMAGE_FORMATS:
        raise CaptureError(f"{where}: field 'image_format' must be one of {IMAGE_FORMATS}, got {image_format!r}")
    green_screen = _typed(data, "green_screen", bool, where)
    holds_object = _typed(data, "holds_object", bool, where)
    object_kind = data.get("object")
    if object_kind is not None:
        _typed(data, "object", str, where)
    for key in ("background", "notes"):
        if key in data:
            _typed(data, key, str, where)
    chroma_key = _read_chroma_key(data, version, where)
    hand_side = data.get("hand_side")
    if hand_side is not None and hand_side not in ("right", "left"):
        raise CaptureError(f"{where}: field 'hand_side' must be 'right' or 'left', got {hand_side!r}")

    allowed = {IMAGES_DIR, MASKS_DIR, GROUND_TRUTH_DIR, SEQUENCE_FILE}
    unknown = sorted(p.name for p in _visible_entries(seq_dir) if p.name not in allowed)
    if unknown:
        raise CaptureError(f"{seq_dir}: unknown entries {unknown} (allowed: {sorted(allowed)})")
    if not (seq_dir / IMAGES_DIR).is_dir():
        raise CaptureError(f"{seq_dir / IMAGES_DIR}: folder not found")

    _per_camera_folders(seq_dir / IMAGES_DIR, cameras, "images")
    images = {c.name: _frame_files(seq_dir / IMAGES_DIR / c.name, image_format, num_frames, f"camera {c.name}")
              for c in cameras}
    masks: dict[str, list[Path]] = {}
    if (seq_dir / MASKS_DIR).exists():
        _per_camera_folders(seq_dir / MASKS_DIR, cameras, "masks")
        masks = {c.name: _frame_files(seq_dir / MASKS_DIR / c.name, "png", num_frames, f"camera {c.name} masks")
                 for c in cameras}
    gt_files: list[Path] | None = None
    gt_masks: dict[str, list[Path]] = {}
    gt_dir = seq_dir / GROUND_TRUTH_DIR
    if gt_dir.exists():
        gt_files = [gt_dir / f"{frame_name(i)}.npz" for i in range(num_frames)]
        present = {p.name for p in _visible_entries(gt_dir) if p.is_file()}
        for p in gt_files:
            if p.name not in present:
                raise CaptureError(f"{p}: missing ground truth of frame {int(p.stem)}")
        if len(present) != num_frames:
            raise CaptureError(f"{gt_dir}: {len(present)} files but sequence.json 'num_frames' is {num_frames}")
        _per_camera_folders(gt_dir / GT_MASKS_DIR, cameras, "ground-truth masks")
        gt_masks = {c.name: _frame_files(gt_dir / GT_MASKS_DIR / c.name, "png", num_frames,
                                         f"camera {c.name} ground-truth masks") for c in cameras}

    if check_images:
        for cam in cameras:
            for path in images[cam.name] + masks.get(cam.name, []) + gt_masks.get(cam.name, []):
                size = _image_size(path)
                if size != (cam.width, cam.height):
                    raise CaptureError(f"{path}: image size {size[0]}x{size[1]} does not match calibration.json "
                                       f"camera {cam.name!r} fields 'width' x 'height' = {cam.width}x{cam.height}")

    frames = tuple(
        FrameRef(
            sequence_id=seq_id,
            index=i,
            time_s=i / fps,
            image_paths={c.name: images[c.name][i] for c in cameras},
            mask_paths={c.name: masks[c.name][i] for c in cameras} if masks else {},
            ground_truth_path=gt_files[i] if gt_files else None,
            gt_mask_paths={c.name: gt_masks[c.name][i] for c in cameras} if gt_masks else {},
        )
        for i in range(num_frames)
    )
    return Sequence(id=seq_id, subject_id=subject, split=split, green_screen=green_screen, fps=fps,
                    holds_object=holds_object, frames=frames, object_kind=object_kind,
                    background=data.get("background", ""), image_format=image_format, chroma_key=chroma_key,
                    hand_side=hand_side)


def read_capture(path: Path | str, *, check_images: bool = True) -> Capture:
    """Read and validate a capture directory.

    Args:
        path: the capture root (holding capture.json).
        check_images: read every image's and mask's header and compare its size with the calibration
            (cheap: pixels are not decoded). Turn off for very large captures.
    Returns:
        The validated `Capture`.
    Raises:
        CaptureError: naming the file and field at fault.
    """
    root = Path(path)
    if not root.is_dir():
        raise CaptureError(f"{root}: capture folder not found")
    name, synthetic, hand_model = _read_header(root)
    version = int(_load_json(root / CAPTURE_FILE)["version"])
    working_width_px = _read_working_width(root)
    cameras = _read_calibration(root)
    subjects = _read_subjects(root)
    seq_root = root / SEQUENCES_DIR
    if not seq_root.is_dir():
        raise CaptureError(f"{seq_root}: folder not found")
    sequences = []
    for seq_dir in _visible_entries(seq_root):
        if not seq_dir.is_dir():
            raise CaptureError(f"{seq_dir}: unexpected file in {SEQUENCES_DIR}/ (expected sequence folders)")
        sequences.append(_read_sequence(seq_dir, cameras, subjects, check_images, version=version))
    return Capture(root=root, name=name, cameras=cameras, subjects=subjects, sequences=tuple(sequences),
                   hand_model=hand_model, synthetic=synthetic, working_width_px=working_width_px)


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

# --- per-frame data --------------------------------------------------------------------------------


def _decode(path: Path, flags: int) -> np.ndarray:
    data = np.fromfile(path, dtype=np.uint8) if path.is_file() else None
    if data is None:
        raise CaptureError(f"{path}: file not found")
    image = cv2.imdecode(data, flags) if data.size else None
    if image is None:
        raise CaptureError(f"{path}: unreadable image (cannot be decoded)")
    # OpenCV decodes a truncated JPEG with a warning (grey bottom rows), and a PNG cut after its pixel data
    # without complaint: check the end markers.
    if data[:2].tobytes() == b"\xff\xd8" and b"\xff\xd9" not in data[-64:].tobytes():
        raise CaptureError(f"{path}: unreadable image (truncated JPEG: no end-of-image marker)")
    if data[:8].tobytes() == PNG_SIGNATURE and b"IEND" not in data[-64:].tobytes():
        raise CaptureError(f"{path}: unreadable image (truncated PNG: no IEND chunk)")
    return image


def _check_shape(image: np.ndarray, path: Path, expected: tuple[int, int] | None) -> None:
    if expected is not None and image.shape[:2] != (expected[1], expected[0]):
        raise CaptureError(f"{path}: image size {image.shape[1]}x{image.shape[0]} does not match the "
                           f"calibration's 'width' x 'height' = {expected[0]}x{expected[1]}")


def load_frame_images(frame: FrameRef, cameras: tuple[Camera, ...] | list[Camera] | None = None
                      ) -> dict[str, np.ndarray]:
    """Decode one frame's images.

    Args:
        frame: from a `Capture`.
        cameras: when given, each image's size is checked against its camera.
    Returns:
        camera name -> (H, W, 3) uint8 RGB.
    """
    sizes = {c.name: (c.width, c.height) for c in cameras} if cameras else {}
    out = {}
    for cam, path in frame.image_paths.items():
        bgr = _decode(path, cv2.IMREAD_COLOR)
        _check_shape(bgr, path, sizes.get(cam))
        out[cam] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return out


def load_frame_masks(frame: FrameRef) -> dict[str, np.ndarray]:
    """camera name -> (H, W) bool foreground (chroma-key) mask; empty when the sequence has none."""
    return {cam: _decode(path, cv2.IMREAD_GRAYSCALE) >= 128 for cam, path in frame.mask_paths.items()}


# numpy parses each .npy header with ast.literal_eval, and CPython 3.11 keeps the AST builder's recursion depth per
# interpreter, not per thread: two threads parsing at once can fail with "SystemError: AST constructor recursion
# depth mismatch" (python/cpython#106905). The verification pool reads ground truth in threads, so the reads take
# turns (a frame's arrays are small: the lock costs little).
_NPY_HEADERS = threading.Lock()


def load_ground_truth(frame: FrameRef, num_vertices: int | None = None) -> GroundTruth:
    """Load and validate one frame's ground truth.

    Args:
        frame: a frame of a sequence with ground truth.
        num_vertices: expected vertex count (e.g. capture.hand_model.num_vertices), or None.
    Returns:
        The `GroundTruth`, hand masks included; arrays as float64 / bool.
    """
    path = frame.ground_truth_path
    if path is None:
        raise CaptureError(f"sequence {frame.sequence_id!r} frame {frame.index}: no ground truth")
    try:
        with _NPY_HEADERS, np.load(path, allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files}
    except FileNotFoundError:
        raise CaptureError(f"{path}: file not found") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise CaptureError(f"{path}: unreadable ground truth ({exc})") from None
    unknown = set(arrays) - set(GT_ARRAYS)
    if unknown:
        raise CaptureError(f"{path}: unknown field(s) {sorted(unknown)}")
    missing = set(GT_ARRAYS) - set(arrays)
    if missing:
        raise CaptureError(f"{path}: missing field(s) {sorted(missing)}")
    cams = tuple(str(c) for c in arrays["camera_names"])
    if set(cams) != set(frame.image_paths) or len(cams) != len(frame.image_paths):
        raise CaptureError(f"{path}: field 'camera_names' {list(cams)} does not match the calibration "
                           f"{list(frame.image_paths)}")
    dims = {-1: num_vertices, -2: len(cams)}
    out: dict[str, np.ndarray] = {}
    for key, (shape, kind) in GT_ARRAYS.items():
        if key == "camera_names":
            continue
        value = arrays[key]
        want = tuple(dims.get(s, s) for s in shape)
        if value.ndim != len(want) or any(w is not None and w != g for w, g in zip(want, value.shape, strict=True)):
            raise CaptureError(f"{path}: field '{key}' must have shape {want} (None = any), got {value.shape}")
        if kind == "b":
            if value.dtype != bool:
                raise CaptureError(f"{path}: field '{key}' must be bool, got {value.dtype}")
            out[key] = value
            continue
        if value.dtype.kind not in "fi":
            raise CaptureError(f"{path}: field '{key}' must be numeric, got {value.dtype}")
        if not np.all(np.isfinite(value)):
            raise CaptureError(f"{path}: field '{key}' contains non-finite numbers")
        out[key] = value.astype(np.float64)
    masks = {}
    for cam, mask_path in frame.gt_mask_paths.items():
        mask = _decode(mask_path, cv2.IMREAD_GRAYSCALE)
        image_path = frame.image_paths[cam]
        w, h = _image_size(image_path)
        if mask.shape != (h, w):
            raise CaptureError(f"{mask_path}: mask size {mask.shape[1]}x{mask.shape[0]} does not match the image "
                               f"{image_path.name} ({w}x{h})")
        masks[cam] = mask >= 128
    return GroundTruth(camera_names=cams, hand_masks=masks, **out)
