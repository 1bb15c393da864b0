"""Reader round trip and one clear error per kind of broken capture."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from workers.capture import (
    CaptureError,
    load_frame_images,
    load_frame_masks,
    load_ground_truth,
    read_capture,
)


def test_round_trip(tiny_capture):
    root, written = tiny_capture
    cap = read_capture(root)
    assert cap.name == "tiny" and cap.synthetic and cap.hand_model.num_vertices == 12
    assert [c.name for c in cap.cameras] == [c.name for c in written["cameras"]]
    np.testing.assert_allclose(cap.cameras[2].K, written["cameras"][2].K)
    assert cap.subjects["subj00"].skin_tone == "#a07e56"
    np.testing.assert_allclose(cap.subjects["subj00"].betas, np.arange(10) / 10)
    assert cap.subjects["subj01"].betas is None
    s0, s1 = cap.sequences
    assert (s0.id, s0.split, s0.green_screen) == ("seq000", "train", True)
    assert s0.has_masks and s0.has_ground_truth
    assert (s1.split, s1.holds_object, s1.object_kind, s1.has_masks, s1.has_ground_truth) == (
        "evaluation", True, "ball", False, False)
    assert [f.index for f in s0.frames] == [0, 1] and s0.frames[1].time_s == pytest.approx(1 / 15)
    images = load_frame_images(s0.frames[1], cap.cameras)
    for name, image in written["images"][("seq000", 1)].items():
        assert np.array_equal(images[name], image)  # PNG: exact, RGB order preserved
    assert set(load_frame_masks(s0.frames[0])) == set(cap.camera_names)
    gt = load_ground_truth(s0.frames[1], cap.hand_model.num_vertices)
    ref = written["gt"][("seq000", 1)]
    for key in ("betas", "pose", "keypoints_3d", "keypoints_2d", "transl", "global_orient"):
        np.testing.assert_allclose(getattr(gt, key), getattr(ref, key))
    np.testing.assert_allclose(gt.vertices, ref.vertices, atol=1e-6)  # stored as float32
    assert np.array_equal(gt.visibility, ref.visibility)
    assert np.array_equal(gt.hand_masks["cam3"], ref.hand_masks["cam3"])


def _edit_json(path: Path, change: Callable[[dict], None]) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def _set(*keys_and_value):
    *keys, value = keys_and_value

    def change(data: dict) -> None:
        for key in keys[:-1]:
            data = data[key]
        data[keys[-1]] = value
    return change


SEQ = Path("sequences/seq000")


def _write_png(path: Path, shape: tuple[int, ...]) -> None:
    cv2.imwrite(str(path), np.zeros(shape, np.uint8))


# (case id, how to break the capture, file named in the message, field or folder named in the message)
BREAKS: list[tuple[str, Callable[[Path], None], str, str]] = [
    ("missing camera folder", lambda r: shutil.rmtree(r / SEQ / "images/cam3"), "seq000/images", "cam3"),
    ("extra camera folder", lambda r: shutil.copytree(r / SEQ / "images/cam1", r / SEQ / "images/cam9"),
     "seq000/images", "cam9"),
    ("image size", lambda r: _write_png(r / SEQ / "images/cam2/000001.png", (40, 48, 3)),
     "cam2/000001.png", "'width' x 'height'"),
    ("mask size", lambda r: _write_png(r / SEQ / "masks/cam5/000000.png", (10, 10)), "masks/cam5/000000.png",
     "'width' x 'height'"),
    ("non-finite calibration", lambda r: _edit_json(
        r / "calibration.json", lambda d: d["cameras"][4]["K"][0].__setitem__(0, float("nan"))),
     "calibration.json", "'K'"),
    ("non-finite fps", lambda r: _edit_json(r / SEQ / "sequence.json", _set("fps", float("inf"))), "sequence.json",
     "'fps'"),
    ("non-finite betas", lambda r: _edit_json(r / "subjects.json", lambda d: d["subjects"][0]["betas"].__setitem__(
        3, float("nan"))), "subjects.json", "'betas'"),
    ("unknown key in capture.json", lambda r: _edit_json(r / "capture.json", _set("colour", 1)), "capture.json",
     "colour"),
    ("unknown key in sequence.json", lambda r: _edit_json(r / SEQ / "sequence.json", _set("framez", 2)),
     "sequence.json", "framez"),
    ("unknown key in a camera", lambda r: _edit_json(r / "calibration.json", lambda d: d["cameras"][0].__setitem__(
        "fov", 1)), "calibration.json", "fov"),
    ("missing key", lambda r: _edit_json(r / SEQ / "sequence.json", lambda d: d.pop("split")), "sequence.json",
     "split"),
    ("unreadable image", lambda r: (r / SEQ / "images/cam6/000000.png").write_bytes(b"not an image"),
     "cam6/000000.png", "unreadable"),
    ("missing frame", lambda r: (r / SEQ / "images/cam7/000001.png").unlink(), "cam7/000001.png", "num_frames"),
    ("frame count mismatch", lambda r: _edit_json(r / SEQ / "sequence.json", _set("num_frames", 1)), "images/cam0",
     "num_frames"),
    ("unknown subject", lambda r: _edit_json(r / SEQ / "sequence.json", _set("subject", "nobody")), "sequence.json",
     "'subject'"),
    ("id differs from folder", lambda r: _edit_json(r / SEQ / "sequence.json", _set("id", "seq999")),
     "sequence.json", "'id'"),
    ("bad id", lambda r: _edit_json(r / "subjects.json", lambda d: d["subjects"][1].__setitem__("id", "a b")),
     "subjects.json", "'id'"),
    ("duplicate subject", lambda r: _edit_json(r / "subjects.json", lambda d: d["subjects"][1].__setitem__(
        "id", "subj00")), "subjects.json", "'id'"),
    ("wrong type", lambda r: _edit_json(r / SEQ / "sequence.json", _set("green_screen", "yes")), "sequence.json",
     "'green_screen'"),
    ("bad split", lambda r: _edit_json(r / SEQ / "sequence.json", _set("split", "test")), "sequence.json", "'split'"),
    ("newer version", lambda r: _edit_json(r / "capture.json", _set("version", 99)), "capture.json", "'version'"),
    ("not json", lambda r: (r / "subjects.json").write_text("{oops"), "subjects.json", "JSON"),
    ("missing calibration", lambda r: (r / "calibration.json").unlink(), "calibration.json", "not found"),
    ("missing ground truth", lambda r: (r / SEQ / "ground_truth/000001.npz").unlink(), "000001.npz", "ground truth"),
    ("stray file", lambda r: (r / SEQ / "notes.txt").write_text("x"), "seq000", "notes.txt"),
]


@pytest.mark.parametrize(("case", "breaker", "file_part", "field_part"), BREAKS, ids=[b[0] for b in BREAKS])
def test_broken_capture_names_file_and_field(tiny_capture, case, breaker, file_part, field_part):
    root, _ = tiny_capture
    read_capture(root)  # valid before
    breaker(root)
    with pytest.raises(CaptureError) as info:
        read_capture(root)
    message = str(info.value)
    assert file_part in message, message
    assert field_part in message, message


def _save_gt(path: Path, **changes) -> None:
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays.update(changes)
    for key in [k for k, v in changes.items() if v is None]:
        arrays.pop(key)
    np.savez(path, **arrays)


@pytest.mark.parametrize(("changes", "field_part"), [
    ({"keypoints_3d": np.full((21, 3), np.nan)}, "'keypoints_3d' contains non-finite"),
    ({"vertices": np.zeros((5, 3))}, "'vertices' must have shape"),
    ({"visibility": np.zeros((8, 21))}, "'visibility' must be bool"),
    ({"extra": np.zeros(2)}, "unknown field(s) ['extra']"),
    ({"pose": None}, "missing field(s) ['pose']"),
    ({"camera_names": np.array(["a", "b"])}, "'camera_names'"),
])
def test_broken_ground_truth_names_file_and_field(tiny_capture, changes, field_part):
    root, _ = tiny_capture
    frame = read_capture(root).sequences[0].frames[0]
    _save_gt(frame.ground_truth_path, **changes)
    with pytest.raises(CaptureError) as info:
        load_ground_truth(frame, num_vertices=12)
    assert "000000.npz" in str(info.value) and field_part in str(info.value), str(info.value)


def test_corrupt_pixels_are_caught_when_decoding(tiny_capture):
    root, _ = tiny_capture
    cap = read_capture(root)
    frame = cap.sequences[1].frames[0]
    path = frame.image_paths["cam1"]
    _, jpg = cv2.imencode(".jpg", np.zeros((48, 64, 3), np.uint8))
    path.write_bytes(jpg.tobytes()[: len(jpg) // 2])  # truncated JPEG under a .png name: header still readable
    with pytest.raises(CaptureError, match=r"cam1/000000\.png: unreadable image"):
        load_frame_images(frame, cap.cameras)
