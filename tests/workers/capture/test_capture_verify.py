"""Full verification of a capture's files (workers.capture.verify): a file cut short or holding bad arrays is
named, whichever check finds it, and a sound capture passes."""

from __future__ import annotations

import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from workers.capture import (
    CaptureError,
    GroundTruth,
    HandModelInfo,
    Subject,
    read_capture,
    verify,
    write_capture_header,
    write_frame,
    write_sequence,
)
from workers.capture.verify import count_files, verify_capture_files
from workers.geometry import default_rig

NUM_VERTICES = 12
FRAMES = 2


def _ground_truth(cameras, rng: np.random.Generator) -> GroundTruth:
    C = len(cameras)
    return GroundTruth(
        betas=rng.normal(size=10), pose=rng.normal(size=45) * 0.1, global_orient=rng.normal(size=3),
        transl=rng.normal(size=3) * 0.01, keypoints_3d=rng.normal(size=(21, 3)) * 0.05,
        vertices=rng.normal(size=(NUM_VERTICES, 3)) * 0.05, keypoints_2d=rng.uniform(0, 40, (C, 21, 2)),
        visibility=rng.random((C, 21)) > 0.3, camera_names=tuple(c.name for c in cameras),
        hand_masks={c.name: rng.random((c.height, c.width)) > 0.5 for c in cameras})


@pytest.fixture
def jpeg_capture(tmp_path: Path) -> Path:
    """One green-screen sequence of JPEG images (noise: each well above 1100 bytes), masks and ground truth."""
    root = tmp_path / "capture"
    rng = np.random.default_rng(1)
    cameras = default_rig(48)
    write_capture_header(root, "jpeg", cameras, [Subject("subj00")],
                         HandModelInfo("test-model", is_mano=False, num_vertices=NUM_VERTICES), synthetic=True)
    write_sequence(root, "seq000", subject_id="subj00", split="train", green_screen=True, fps=15.0,
                   num_frames=FRAMES, holds_object=False, camera_names=[c.name for c in cameras], image_format="jpg",
                   with_masks=True, with_ground_truth=True)
    for f in range(FRAMES):
        images = {c.name: rng.integers(0, 256, (c.height, c.width, 3), dtype=np.uint8) for c in cameras}
        masks = {c.name: rng.random((c.height, c.width)) > 0.5 for c in cameras}
        gt = _ground_truth(cameras, rng)
        write_frame(root, "seq000", f, images, image_format="jpg", masks=masks, ground_truth=gt)
    return root


def _cut(path: Path, size: int) -> None:
    data = path.read_bytes()
    assert len(data) > size
    path.write_bytes(data[:size])


def _broken(root: Path) -> str:
    capture = read_capture(root)  # the structure and the headers pass: only a full decode finds these
    with pytest.raises(CaptureError) as error:
        verify_capture_files(capture)
    return str(error.value)


def test_a_sound_capture_passes_in_parallel_and_alone_with_progress(jpeg_capture):
    capture = read_capture(jpeg_capture)
    cameras = len(capture.cameras)
    expected = FRAMES * (cameras + cameras + 1)  # images, chroma-key masks, ground-truth files
    seen: list[tuple[int, int]] = []
    assert count_files(capture) == expected
    assert verify_capture_files(capture, progress=lambda done, total: seen.append((done, total))) == expected
    assert verify_capture_files(capture, threads=1) == expected
    assert seen[-1] == (expected, expected) and len(seen) == expected


def test_a_jpeg_cut_at_1100_bytes_is_named(jpeg_capture):
    image = jpeg_capture / "sequences/seq000/images/cam3/000001.jpg"
    _cut(image, 1100)
    message = _broken(jpeg_capture)
    assert str(image) in message and "unreadable image" in message and message.startswith("1 broken file(s)")


def _huffman_tables_offset(data: bytes) -> int:
    """Where the first DHT segment's table bytes start (after its marker, length and class/id byte)."""
    return data.index(b"\xff\xc4") + 5


def test_a_jpeg_whose_huffman_tables_are_zeroed_is_named(jpeg_capture):
    # Past the header read_capture checks, so only a decode finds it, and the 1/8-scale decode does.
    image = jpeg_capture / "sequences/seq000/images/cam2/000000.jpg"
    data = bytearray(image.read_bytes())
    start = _huffman_tables_offset(bytes(data))
    data[start:start + 16] = bytes(16)  # code counts all zero: no valid Huffman table
    image.write_bytes(bytes(data))
    message = _broken(jpeg_capture)
    assert str(image) in message and "unreadable image" in message and message.startswith("1 broken file(s)")


def test_a_jpeg_is_checked_at_one_eighth_scale_against_its_camera(jpeg_capture, monkeypatch):
    flags: list[int] = []
    decode = verify._decode
    monkeypatch.setattr(verify, "_decode", lambda path, f: flags.append(f) or decode(path, f))
    capture = read_capture(jpeg_capture)
    verify_capture_files(capture, threads=1)
    assert flags.count(cv2.IMREAD_REDUCED_COLOR_8) == FRAMES * len(capture.cameras)  # every image, no mask
    camera = capture.cameras[0]
    frame = capture.sequences[0].frames[0]
    wrong = verify._Check(frame.image_paths[camera.name], "image", (camera.width + 16, camera.height))
    assert "does not match the calibration's 'width' x 'height'" in verify._run(wrong, None)
    right = verify._Check(frame.image_paths[camera.name], "image", (camera.width, camera.height))
    assert verify._run(right, None) is None


@pytest.mark.parametrize("keep", [0.5, -12], ids=["half", "all-but-IEND"])
def test_a_truncated_mask_png_is_named(jpeg_capture, keep):
    mask = jpeg_capture / "sequences/seq000/masks/cam0/000000.png"
    size = mask.stat().st_size
    _cut(mask, int(size * keep) if keep > 0 else size + keep)
    message = _broken(jpeg_capture)
    assert str(mask) in message and "1 broken file(s)" in message


def test_a_truncated_ground_truth_mask_png_is_named(jpeg_capture):
    mask = jpeg_capture / "sequences/seq000/ground_truth/masks/cam5/000001.png"
    _cut(mask, mask.stat().st_size // 2)
    assert str(mask) in _broken(jpeg_capture)


def test_a_truncated_ground_truth_npz_is_named(jpeg_capture):
    gt = jpeg_capture / "sequences/seq000/ground_truth/000001.npz"
    _cut(gt, gt.stat().st_size // 2)
    message = _broken(jpeg_capture)
    assert str(gt) in message and "unreadable ground truth" in message


@pytest.mark.parametrize(("field", "value", "problem"), [
    ("transl", np.array([0.0, np.nan, 0.0]), "non-finite"),
    ("keypoints_3d", np.zeros((20, 3)), "shape"),
    ("visibility", np.zeros((8, 21)), "must be bool"),
])
def test_ground_truth_arrays_are_checked_for_shape_dtype_and_finiteness(jpeg_capture, field, value, problem):
    gt = jpeg_capture / "sequences/seq000/ground_truth/000000.npz"
    with np.load(gt) as npz:
        arrays = {key: npz[key] for key in npz.files}
    arrays[field] = value
    np.savez_compressed(gt, **arrays)
    message = _broken(jpeg_capture)
    assert str(gt) in message and field in message and problem in message


def test_a_member_with_a_bad_checksum_is_named(jpeg_capture):
    gt = jpeg_capture / "sequences/seq000/ground_truth/000000.npz"
    with zipfile.ZipFile(gt) as archive:
        info = archive.infolist()[0]
    data = bytearray(gt.read_bytes())
    start = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
    data[start] ^= 0xFF  # one byte inside the first member's data: the archive's structure is intact
    gt.write_bytes(bytes(data))
    assert str(gt) in _broken(jpeg_capture)


def test_every_broken_file_is_named_in_capture_order(jpeg_capture):
    first = jpeg_capture / "sequences/seq000/images/cam1/000000.jpg"
    second = jpeg_capture / "sequences/seq000/ground_truth/000001.npz"
    _cut(second, 100)
    _cut(first, 1100)
    message = _broken(jpeg_capture)
    assert message.startswith("2 broken file(s)") and message.index(str(first)) < message.index(str(second))
