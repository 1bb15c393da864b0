"""Assemble a capture from one video or one image folder per camera (`handloop capture assemble`).

Sources are matched to the calibration's cameras by name (`<camera>.<video ext>` or `<camera>/`),
synchronised by frame index plus a per-camera offset (source frame = offset + i * every for output
frame i) and streamed: each camera is read by one worker process that holds one frame at a time, so
memory does not grow with the number of frames. Images stay at full resolution: JPEG and PNG files of
the right size are copied byte for byte after the checks `handloop import` makes (header, size, end
marker); MJPEG video frames are stored as the JPEGs they are, other videos' frames are encoded as
JPEG. The capture is written into a hidden temporary folder beside `out`, validated with the reader,
and renamed into place: a failure leaves nothing behind.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from dataclasses import dataclass
from multiprocessing import get_all_start_methods, get_context
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from workers.capture.chroma import ChromaKey, key_mask, preview
from workers.capture.reader import read_capture
from workers.capture.schema import (
    IMAGES_DIR,
    MASKS_DIR,
    CaptureError,
    HandModelInfo,
    Subject,
    frame_name,
)
from workers.capture.writer import JPEG_QUALITY, PNG_PARAMS, write_capture_header, write_sequence
from workers.geometry.camera import Camera

VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg")
IMAGE_SUFFIXES = {".jpg": "jpg", ".jpeg": "jpg", ".png": "png"}
PREVIEW_DIR = "previews"
DEFAULT_WORKING_WIDTH_PX = 640


@dataclass(frozen=True)
class CameraSource:
    """Where one camera's frames come from.

    Attributes:
        camera: the calibration's camera name.
        path: the video file or the image folder.
        files: the image files in frame order (empty for a video).
        count: frames available (a video's container count).
    """

    camera: str
    path: Path
    files: tuple[Path, ...]
    count: int

    @property
    def is_video(self) -> bool:
        return not self.files


@dataclass(frozen=True)
class AssembleResult:
    """What `assemble_capture` wrote."""

    root: Path
    num_frames: int
    num_cameras: int
    image_format: str
    seconds: float
    masks: bool

    @property
    def frames_per_s(self) -> float:
        return self.num_frames / self.seconds if self.seconds > 0 else math.inf


def _natural_key(path: Path) -> list[Any]:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def _video_count(path: Path, camera: str) -> int:
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise CaptureError(f"{path}: camera {camera!r}: OpenCV cannot open this video")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()
    if count <= 0:
        raise CaptureError(f"{path}: camera {camera!r}: the video reports no frame count")
    return count


def find_sources(cameras: list[Camera], *, videos: Path | None = None,
                 images: Path | None = None) -> list[CameraSource]:
    """One source per camera, in calibration order; missing or unknown names raise CaptureError naming them."""
    if (videos is None) == (images is None):
        raise CaptureError("give exactly one of a videos folder or an images folder")
    folder = Path(videos or images)  # type: ignore[arg-type]
    if not folder.is_dir():
        raise CaptureError(f"{folder}: folder not found")
    names = [c.name for c in cameras]
    entries = [p for p in folder.iterdir() if not p.name.startswith(".")]
    if videos is not None:
        found = {p.stem: p for p in entries if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES}
        what = f"videos ({'/'.join(VIDEO_SUFFIXES)})"
        stray = sorted(p.name for p in entries if p.stem not in names or p.suffix.lower() not in VIDEO_SUFFIXES)
    else:
        found = {p.name: p for p in entries if p.is_dir()}
        what = "image folders"
        stray = sorted(p.name for p in entries if p.name not in names or not p.is_dir())
    missing = [n for n in names if n not in found]
    if missing:
        raise CaptureError(f"{folder}: no {what} for camera(s) {missing} of the calibration {names}")
    if stray:
        raise CaptureError(f"{folder}: entries {stray} match no camera of the calibration {names}")
    sources = []
    for name in names:
        path = found[name]
        if videos is not None:
            sources.append(CameraSource(name, path, (), _video_count(path, name)))
            continue
        files = sorted((p for p in path.iterdir() if not p.name.startswith(".")), key=_natural_key)
        others = [p.name for p in files if p.suffix.lower() not in IMAGE_SUFFIXES]
        if others:
            raise CaptureError(f"{path}: camera {name!r}: files that are not JPEG or PNG images: {others[:3]}")
        if not files:
            raise CaptureError(f"{path}: camera {name!r}: no images")
        sources.append(CameraSource(name, path, tuple(files), len(files)))
    return sources


def read_offsets(path: Path | None, cameras: list[Camera]) -> dict[str, int]:
    """Per-camera frame offsets from a JSON object {camera: non-negative int}; absent cameras get 0."""
    if path is None:
        return {c.name: 0 for c in cameras}
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise CaptureError(f"{path}: file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaptureError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise CaptureError(f"{path}: expected an object {{camera: frame offset}}")
    return complete_offsets(data, cameras, str(path))


def complete_offsets(offsets: dict[str, Any], cameras: list[Camera], where: str = "offsets") -> dict[str, int]:
    """Validated offsets for every camera (absent ones 0); unknown cameras and bad values raise."""
    out = {c.name: 0 for c in cameras}
    for name, value in offsets.items():
        if name not in out:
            raise CaptureError(f"{where}: camera {name!r} is not in the calibration {list(out)}")
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 10_000_000:
            raise CaptureError(f"{where}: camera {name!r}: offset must be a non-negative integer of frames, "
                               f"got {value!r}")
        out[name] = value
    return out


def plan_frames(sources: list[CameraSource], offsets: dict[str, int], every: int, trim: bool) -> int:
    """Output frames: equal per camera after offsets and subsampling, or (trim) the shortest camera's."""
    counts = {s.camera: len(range(offsets[s.camera], s.count, every)) for s in sources}
    empty = [c for c, n in counts.items() if n == 0]
    if empty:
        raise CaptureError(f"camera(s) {empty}: no frames left after the offset (frames available: "
                           f"{ {s.camera: s.count for s in sources if s.camera in empty} })")
    if len(set(counts.values())) > 1 and not trim:
        values = list(counts.values())
        usual = max(set(values), key=values.count)  # what most cameras have
        odd = {c: n for c, n in counts.items() if n != usual}
        raise CaptureError(f"frame counts differ between cameras after offsets and --every {every}: camera(s) "
                           + ", ".join(f"{c!r} ({n})" for c, n in odd.items())
                           + f" against {usual} for the others (all: {counts}); fix the offsets, or pass --trim "
                           f"to keep {min(values)} frames")
    return min(counts.values())


@dataclass(frozen=True)
class _CameraJob:
    source: CameraSource
    width: int
    height: int
    offset: int
    every: int
    num_frames: int
    image_format: str
    images_dir: Path
    masks_dir: Path | None
    chroma: ChromaKey | None
    preview_path: Path | None


def _check_size(camera: str, where: Path, width: int, height: int, job: _CameraJob) -> None:
    if (width, height) != (job.width, job.height):
        raise CaptureError(f"{where}: camera {camera!r}: image size {width}x{height} does not match the "
                           f"calibration's {job.width}x{job.height}")


HEAD_BYTES = 256 * 1024  # enough for a JPEG's or PNG's header with EXIF and ICC profile; longer ones are re-read
TAIL_BYTES = 64


def _check_file_end(path: Path, head: bytes, tail: bytes, camera: str) -> None:
    """Truncation shows at the end of the file: a JPEG ends with the EOI marker, a PNG with its IEND chunk."""
    if head[:2] == b"\xff\xd8" and b"\xff\xd9" not in tail:
        raise CaptureError(f"{path}: camera {camera!r}: truncated JPEG (no end-of-image marker)")
    if head[:8] == b"\x89PNG\r\n\x1a\n" and b"IEND" not in tail[-12:]:
        raise CaptureError(f"{path}: camera {camera!r}: truncated PNG (no IEND chunk)")


def _header_size(path: Path, head: bytes, camera: str) -> tuple[int, int]:
    """(width, height) from the image header (PIL parses it without decoding the pixels)."""
    for data in (head, None):
        try:
            with Image.open(io.BytesIO(data) if data is not None else path) as header:
                return header.size
        except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
            if data is None or len(head) < HEAD_BYTES:  # the whole file was read: the header is bad
                raise CaptureError(f"{path}: camera {camera!r}: unreadable image "
                                   f"({exc.__class__.__name__}: {exc})") from None
    raise AssertionError("unreachable")


def _decode(path: Path, data: bytes, camera: str) -> np.ndarray:
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data else None
    if bgr is None:
        raise CaptureError(f"{path}: camera {camera!r}: unreadable image (cannot be decoded)")
    return bgr


def _image_frames(job: _CameraJob) -> Iterator[tuple[Path | None, np.ndarray | None]]:
    """Per frame: (the file to copy as it is, or None; the decoded BGR image, or None when only copied).

    A file stored as it is gets the checks `handloop import` makes (header, size, end marker), reading
    only its head and tail, and is copied by the kernel (shutil.copyfile): decoding would cost 5-10 times
    more, and OpenCV's decoder accepts corrupt scans with a warning anyway.
    """
    camera = job.source.camera
    for i in range(job.num_frames):
        path = job.source.files[job.offset + i * job.every]
        copy = IMAGE_SUFFIXES[path.suffix.lower()] == job.image_format and job.chroma is None
        with open(path, "rb") as f:
            head = f.read(HEAD_BYTES) if copy else f.read()
            if not head:
                raise CaptureError(f"{path}: camera {camera!r}: empty file")
            f.seek(max(0, f.seek(0, os.SEEK_END) - TAIL_BYTES))
            tail = f.read()
        _check_file_end(path, head, tail, camera)
        if copy:
            size = _header_size(path, head, camera)
            bgr = None
        else:
            bgr = _decode(path, head, camera)
            size = (bgr.shape[1], bgr.shape[0])
        _check_size(camera, path, size[0], size[1], job)
        yield (path if copy else None), bgr


def _mjpeg_packets(job: _CameraJob) -> cv2.VideoCapture | None:
    """A capture returning an MJPEG video's packets undecoded, when they are standalone JPEGs of the right
    size (they are what a decode and re-encode would only approximate, at a fraction of the cost); else None."""
    if job.chroma is not None or job.image_format != "jpg":
        return None
    cap = cv2.VideoCapture(str(job.source.path), cv2.CAP_FFMPEG)
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little") if cap.isOpened() else b""
    if fourcc.upper() not in (b"MJPG", b"AVRN", b"MJPA") or not cap.set(cv2.CAP_PROP_FORMAT, -1):
        cap.release()
        return None
    ok, packet = cap.read()
    data = packet.tobytes() if ok and packet is not None else b""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data[:2] == b"\xff\xd8" else None
    cap.release()
    if image is None or image.shape[:2] != (job.height, job.width):
        return None  # e.g. AVI1 packets without Huffman tables: decode and re-encode instead
    cap = cv2.VideoCapture(str(job.source.path), cv2.CAP_FFMPEG)
    cap.set(cv2.CAP_PROP_FORMAT, -1)
    return cap


def _video_frames(job: _CameraJob) -> Iterator[tuple[bytes | None, np.ndarray | None]]:
    """Per output frame (JPEG bytes to store as they are, or None; the decoded BGR frame, or None)."""
    packets = _mjpeg_packets(job)
    cap = packets or cv2.VideoCapture(str(job.source.path))
    where = f"{job.source.path}: camera {job.source.camera!r}"
    try:
        position = 0
        for i in range(job.num_frames):
            target = job.offset + i * job.every
            while position < target:  # skipped frames are demuxed, not decoded
                if not cap.grab():
                    break
                position += 1
            ok, frame = cap.read()
            position += 1
            if not ok or frame is None or frame.size == 0:
                raise CaptureError(f"{where}: the video ends at frame {position - 1}, before source frame {target} "
                                   f"(output frame {i}); its header claimed {job.source.count} frames")
            if packets is None:
                _check_size(job.source.camera, job.source.path, frame.shape[1], frame.shape[0], job)
                yield None, frame
                continue
            data = frame.tobytes()
            if data[:2] != b"\xff\xd8" or b"\xff\xd9" not in data[-TAIL_BYTES:]:
                raise CaptureError(f"{where}: frame {target} is not a complete JPEG (truncated or corrupt video)")
            size = _header_size(job.source.path, data[:HEAD_BYTES], job.source.camera)
            _check_size(job.source.camera, job.source.path, size[0], size[1], job)
            yield data, None
    finally:
        cap.release()


def _run_camera(job: _CameraJob, progress: Any = None) -> None:
    """Write one camera's frames (in a worker process or inline); `progress` is a queue or a callable."""
    frames = _video_frames(job) if job.source.is_video else _image_frames(job)
    params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if job.image_format == "jpg" else PNG_PARAMS
    for i, (source, bgr) in enumerate(frames):
        target = job.images_dir / f"{frame_name(i)}.{job.image_format}"
        if isinstance(source, bytes):
            target.write_bytes(source)
        elif source is not None:
            shutil.copyfile(source, target)
        elif not cv2.imwrite(str(target), bgr, params):
            raise CaptureError(f"{target}: could not write the image")
        if job.chroma is not None:
            mask = key_mask(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), job.chroma)
            if not cv2.imwrite(str(job.masks_dir / f"{frame_name(i)}.png"), mask.astype(np.uint8) * 255,
                               PNG_PARAMS):
                raise CaptureError(f"{job.masks_dir}: could not write the mask of frame {i}")
            if i == 0 and job.preview_path is not None:
                np.save(job.preview_path, np.dstack([cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), mask.astype(np.uint8)]))
        if progress is not None:
            progress(1) if callable(progress) else progress.put(1)


def _image_format(sources: list[CameraSource]) -> str:
    """The stored format: the source images' own when they all share one (copied as-is), else JPEG."""
    if any(s.is_video for s in sources):
        return "jpg"
    formats = {IMAGE_SUFFIXES[f.suffix.lower()] for s in sources for f in s.files}
    return formats.pop() if len(formats) == 1 else "jpg"


def _new_output(out: Path, force: bool) -> Path:
    out = Path(out)
    if out.exists() and not (out.is_dir() and not any(out.iterdir())) and not force:
        raise CaptureError(f"{out}: exists and is not empty; pass --force to replace it")
    out.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))


def assemble_capture(calibration: list[Camera], out: Path, *, videos: Path | None = None, images: Path | None = None,
                     offsets: dict[str, int] | None = None, every: int = 1, trim: bool = False,
                     green_screen: bool = False, chroma: ChromaKey | None = None, fps: float = 30.0,
                     name: str | None = None, sequence_id: str = "seq000", subject_id: str = "subject0",
                     hand_model: HandModelInfo | None = None, working_width_px: int | None = None,
                     workers: int = 0, force: bool = False,
                     progress: Callable[[int], None] | None = None) -> AssembleResult:
    """Write a capture (one sequence) from per-camera videos or image folders.

    Args:
        calibration: the rig, in the order the capture keeps.
        out: the capture folder to create (new or empty; `force` replaces an existing one).
        videos, images: exactly one: a folder of `<camera>.<ext>` videos or of `<camera>/` image folders.
        offsets: camera -> frames to skip at its start (synchronisation); absent cameras 0.
        every: keep every n-th frame.
        trim: cut every camera to the shortest instead of refusing unequal counts.
        green_screen: recorded on a green screen: masks are keyed with `chroma` and the split is "train".
        chroma: keyer settings (default ChromaKey()); only with green_screen.
        fps: the source frame rate; the capture's is fps / every.
        working_width_px: the width networks and thumbnails derive at (default min(640, narrowest camera)).
        workers: processes (0: one per core, at most one per camera; 1: in this process).
        progress: called with 1 per camera frame written.
    Raises:
        CaptureError: naming the camera and file at fault; nothing is left at `out`.
    """
    started = time.perf_counter()
    if not isinstance(every, int) or every < 1:
        raise CaptureError(f"--every must be a positive integer, got {every!r}")
    if not math.isfinite(fps) or fps <= 0:
        raise CaptureError(f"fps must be a positive number, got {fps!r}")
    if chroma is not None and not green_screen:
        raise CaptureError("chroma-key settings need --green-screen")
    sources = find_sources(calibration, videos=videos, images=images)
    offsets = complete_offsets(offsets or {}, calibration)
    num_frames = plan_frames(sources, offsets, every, trim)
    image_format = _image_format(sources)
    chroma = (chroma or ChromaKey()) if green_screen else None
    width = working_width_px or min(DEFAULT_WORKING_WIDTH_PX, min(c.width for c in calibration))
    out = Path(out)
    tmp = _new_output(out, force)
    try:
        write_capture_header(tmp, name or out.resolve().name, calibration, [Subject(subject_id)],
                             hand_model or HandModelInfo("handloop-builtin v1", is_mano=False), synthetic=False,
                             description="Assembled by `handloop capture assemble`.", working_width_px=width)
        seq_dir = write_sequence(tmp, sequence_id, subject_id=subject_id,
                                 split="train" if green_screen else "evaluation", green_screen=green_screen,
                                 fps=fps / every, num_frames=num_frames, holds_object=False,
                                 camera_names=[c.name for c in calibration], image_format=image_format,
                                 background="green screen" if green_screen else "",
                                 with_masks=green_screen, chroma_key=chroma.to_dict() if chroma else None)
        preview_tmp = Path(tempfile.mkdtemp(prefix=".preview-", dir=tmp)) if chroma else None
        jobs = [_CameraJob(s, cam.width, cam.height, offsets[cam.name], every, num_frames, image_format,
                           seq_dir / IMAGES_DIR / cam.name, seq_dir / MASKS_DIR / cam.name if chroma else None,
                           chroma, preview_tmp / f"{cam.name}.npy" if preview_tmp else None)
                    for s, cam in zip(sources, calibration, strict=True)]
        _run_jobs(jobs, workers, progress)
        if preview_tmp is not None:
            _write_preview(tmp, sequence_id, [np.load(j.preview_path) for j in jobs])  # type: ignore[arg-type]
            shutil.rmtree(preview_tmp)

        read_capture(tmp)  # the same checks as `handloop import`, before anything appears at `out`
        if out.exists():
            shutil.rmtree(out) if out.is_dir() else out.unlink()
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return AssembleResult(root=out, num_frames=num_frames, num_cameras=len(calibration), image_format=image_format,
                          seconds=time.perf_counter() - started, masks=green_screen)


def _write_preview(root: Path, sequence_id: str, stacks: list[np.ndarray]) -> None:
    grid = preview([s[..., :3] for s in stacks], [s[..., 3] > 0 for s in stacks])
    folder = root / PREVIEW_DIR
    folder.mkdir(exist_ok=True)
    path = folder / f"chroma_key_{sequence_id}.jpg"
    if not cv2.imwrite(str(path), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90]):
        raise CaptureError(f"{path}: could not write the chroma-key preview")


def _run_jobs(jobs: list[_CameraJob], workers: int, progress: Callable[[int], None] | None) -> None:
    workers = workers or min(len(jobs), os.cpu_count() or 1)
    if workers <= 1:
        for job in jobs:
            _run_camera(job, progress)
        return
    context = get_context("fork" if "fork" in get_all_start_methods() else "spawn")
    with context.Manager() as manager:
        queue = manager.Queue()
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=context) as pool:
            futures = [pool.submit(_run_camera, job, queue) for job in jobs]
            pending = set(futures)
            while pending:
                done, pending = wait(pending, timeout=0.2, return_when=FIRST_EXCEPTION)
                _drain(queue, progress)
                for future in done:
                    if future.exception() is not None:
                        for other in pending:
                            other.cancel()
                        raise future.exception()  # type: ignore[misc]
            _drain(queue, progress)


def _drain(queue: Any, progress: Callable[[int], None] | None) -> None:
    count = 0
    while not queue.empty():
        count += queue.get_nowait()
    if count and progress is not None:
        progress(count)
