"""`assemble_capture` / `handloop capture assemble`: per-camera videos and image folders into a capture."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from backend.cli.main import app
from workers.capture import load_frame_images, load_frame_masks, read_capture
from workers.capture.assemble import assemble_capture
from workers.capture.chroma import ChromaKey
from workers.capture.schema import CaptureError
from workers.geometry.camera import save_calibration
from workers.geometry.rig import default_rig

WIDTH = 160
SOURCE_FRAMES = 9


def _frame(camera: int, index: int, height: int, width: int, green: bool = False) -> np.ndarray:
    """(H, W, 3) uint8 RGB: a bright square whose position encodes the source frame index."""
    rgb = np.zeros((height, width, 3), np.uint8)
    rgb[:] = (0, 177, 64) if green else (40 + 20 * camera, 60, 90)
    x, y = 4 + 8 * index, 10 + 3 * camera
    rgb[y:y + 20, x:x + 16] = (230, 200, 170)
    return rgb


def _write_sources(root: Path, cameras, offsets: dict[str, int], green: bool = False) -> tuple[Path, Path]:
    """One MJPG video per camera and, from the decoded video, one PNG folder per camera: the same frames."""
    videos, images = root / "videos", root / "images"
    videos.mkdir()
    for k, cam in enumerate(cameras):
        path = videos / f"{cam.name}.avi"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (cam.width, cam.height))
        assert writer.isOpened()
        for i in range(SOURCE_FRAMES + offsets.get(cam.name, 0)):
            index = i - offsets.get(cam.name, 0)  # the first `offset` frames come before the sync point
            writer.write(cv2.cvtColor(_frame(k, max(index, 0) if index >= 0 else 9, cam.height, cam.width, green),
                                      cv2.COLOR_RGB2BGR))
        writer.release()
        folder = images / cam.name
        folder.mkdir(parents=True)
        cap = cv2.VideoCapture(str(path))
        n = 0
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            cv2.imwrite(str(folder / f"img{n}.png"), bgr)  # unpadded numbers: sorted naturally
            n += 1
        cap.release()
        assert n == SOURCE_FRAMES + offsets.get(cam.name, 0)
    return videos, images


@pytest.fixture
def rig():
    return default_rig(WIDTH)[:4]


def test_videos_assemble_into_the_same_frames_as_image_folders(rig, tmp_path: Path) -> None:
    offsets = {"cam1": 2, "cam3": 1}
    videos, images = _write_sources(tmp_path, rig, offsets)
    from_videos = assemble_capture(rig, tmp_path / "a", videos=videos, offsets=offsets, every=2, workers=2)
    from_images = assemble_capture(rig, tmp_path / "b", images=images, offsets=offsets, every=2, workers=1)
    assert from_videos.num_frames == from_images.num_frames == 5  # source frames 0, 2, 4, 6, 8
    assert (from_videos.image_format, from_images.image_format) == ("jpg", "png")
    a, b = read_capture(tmp_path / "a"), read_capture(tmp_path / "b")
    assert a.working_width_px == WIDTH and a.sequences[0].fps == 15.0
    for fa, fb in zip(a.sequences[0].frames, b.sequences[0].frames, strict=True):
        ia, ib = load_frame_images(fa, a.cameras), load_frame_images(fb, b.cameras)
        for k, cam in enumerate(rig):
            diff = np.abs(ia[cam.name].astype(int) - ib[cam.name].astype(int))
            assert diff.mean() < 2.0, (cam.name, fa.index)
            # synchronised: the frame shows source frame 2 i (the square's position), for every camera
            expected = _frame(k, 2 * fa.index, cam.height, cam.width)
            others = [_frame(k, j, cam.height, cam.width) for j in range(SOURCE_FRAMES)]
            errors = [np.abs(ia[cam.name].astype(int) - o).mean() for o in others]
            assert int(np.argmin(errors)) == 2 * fa.index
            assert np.abs(ib[cam.name].astype(int) - expected).mean() < 4.0


def test_image_files_are_kept_byte_for_byte(rig, tmp_path: Path) -> None:
    _, images = _write_sources(tmp_path, rig, {})
    assemble_capture(rig, tmp_path / "c", images=images, workers=1)
    cap = read_capture(tmp_path / "c")
    frame = cap.sequences[0].frames[3]
    assert frame.image_paths["cam2"].read_bytes() == (images / "cam2" / "img3.png").read_bytes()


def test_names_and_counts_that_do_not_match_are_refused(rig, tmp_path: Path) -> None:
    videos, _images = _write_sources(tmp_path, rig, {"cam2": 3})
    with pytest.raises(CaptureError, match=r"frame counts differ .*camera\(s\) 'cam2' \(12\) against 9"):
        assemble_capture(rig, tmp_path / "x", videos=videos)  # cam2 has 3 extra frames without its offset
    trimmed = assemble_capture(rig, tmp_path / "t", videos=videos, trim=True, workers=1)
    assert trimmed.num_frames == SOURCE_FRAMES
    (videos / "cam1.avi").rename(videos / "camera1.avi")
    with pytest.raises(CaptureError, match=r"no videos .* for camera\(s\) \['cam1'\]"):
        assemble_capture(rig, tmp_path / "x", videos=videos)
    (videos / "camera1.avi").rename(videos / "cam1.avi")
    (videos / "cam9.avi").write_bytes(b"")
    with pytest.raises(CaptureError, match=r"entries \['cam9.avi'\] match no camera"):
        assemble_capture(rig, tmp_path / "x", videos=videos)
    assert not (tmp_path / "x").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_bad_images_and_offsets_are_refused_and_nothing_is_left(rig, tmp_path: Path) -> None:
    _, images = _write_sources(tmp_path, rig, {})
    small = np.zeros((10, 10, 3), np.uint8)
    cv2.imwrite(str(images / "cam3" / "img4.png"), small)
    with pytest.raises(CaptureError, match=r"img4.png: camera 'cam3': image size 10x10 does not match"):
        assemble_capture(rig, tmp_path / "x", images=images, workers=2)
    cv2.imwrite(str(images / "cam3" / "img4.png"), np.zeros((rig[3].height, rig[3].width, 3), np.uint8))
    jpg = images / "cam0" / "img5.jpg"
    _ok, data = cv2.imencode(".jpg", np.zeros((rig[0].height, rig[0].width, 3), np.uint8))
    jpg.write_bytes(data.tobytes()[:-200])
    (images / "cam0" / "img5.png").unlink()
    with pytest.raises(CaptureError, match=r"img5.jpg: camera 'cam0': (unreadable|truncated)"):
        assemble_capture(rig, tmp_path / "x", images=images, workers=1)
    assert not (tmp_path / "x").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    jpg.write_bytes(b"not an image at all")
    with pytest.raises(CaptureError, match=r"img5.jpg: camera 'cam0': unreadable image"):
        assemble_capture(rig, tmp_path / "x", images=images, workers=1)
    bad = tmp_path / "offsets.json"
    bad.write_text(json.dumps({"cam1": -2}))
    runner = CliRunner()
    save_calibration(rig, tmp_path / "calibration.json")
    result = runner.invoke(app, ["capture", "assemble", "--calibration", str(tmp_path / "calibration.json"),
                                 "--images", str(images), "--offsets", str(bad), "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "camera 'cam1': offset must be a non-negative integer" in result.output


def test_green_screen_masks_settings_and_preview(rig, tmp_path: Path) -> None:
    videos, _ = _write_sources(tmp_path, rig, {}, green=True)
    save_calibration(rig, tmp_path / "calibration.json")
    result = CliRunner().invoke(app, ["capture", "assemble", "--calibration", str(tmp_path / "calibration.json"),
                                      "--videos", str(videos), "--green-screen", "--key-tolerance", "40",
                                      "--every", "3", "--out", str(tmp_path / "g")])
    assert result.exit_code == 0, result.output
    cap = read_capture(tmp_path / "g")
    seq = cap.sequences[0]
    assert seq.green_screen and seq.split == "train" and seq.has_masks and len(seq.frames) == 3
    assert seq.chroma_key == ChromaKey(tolerance_deg=40.0).to_dict()
    mask = load_frame_masks(seq.frames[1])["cam2"]
    expected = np.zeros_like(mask)
    x, y = 4 + 8 * 3, 10 + 3 * 2
    expected[y:y + 20, x:x + 16] = True
    assert (mask != expected).mean() < 0.02
    assert (tmp_path / "g" / "previews" / "chroma_key_seq000.jpg").is_file()


def test_version_2_keys_in_a_version_1_capture_are_refused(rig, tmp_path: Path) -> None:
    _, images = _write_sources(tmp_path, rig, {})
    assemble_capture(rig, tmp_path / "c", images=images, workers=1)
    header = json.loads((tmp_path / "c" / "capture.json").read_text())
    assert header["version"] == 2
    header["version"] = 1
    (tmp_path / "c" / "capture.json").write_text(json.dumps(header))
    with pytest.raises(CaptureError, match=r"\['working_width_px'\] need capture.json 'version' 2"):
        read_capture(tmp_path / "c")



def test_a_sequence_names_its_own_hand_in_a_version_2_capture(rig, tmp_path: Path) -> None:
    _, images = _write_sources(tmp_path, rig, {})
    assemble_capture(rig, tmp_path / "c", images=images, workers=1)
    path = tmp_path / "c" / "sequences" / "seq000" / "sequence.json"
    data = json.loads(path.read_text())
    assert read_capture(tmp_path / "c").sequences[0].hand_side is None  # the capture's hand_model.side
    path.write_text(json.dumps({**data, "hand_side": "left"}))
    assert read_capture(tmp_path / "c").sequences[0].hand_side == "left"
    path.write_text(json.dumps({**data, "hand_side": "both"}))
    with pytest.raises(CaptureError, match=r"sequence\.json: field 'hand_side' must be 'right' or 'left', got 'both'"):
        read_capture(tmp_path / "c")
    path.write_text(json.dumps({**data, "hand_side": "left"}))
    header = json.loads((tmp_path / "c" / "capture.json").read_text())
    del header["working_width_px"]
    (tmp_path / "c" / "capture.json").write_text(json.dumps({**header, "version": 1}))
    with pytest.raises(CaptureError, match=r"\['hand_side'\] need capture.json 'version' 2"):
        read_capture(tmp_path / "c")


def test_mjpeg_frames_are_stored_as_the_jpegs_in_the_video(rig, tmp_path: Path) -> None:
    videos, _ = _write_sources(tmp_path, rig, {})
    assemble_capture(rig, tmp_path / "m", videos=videos, every=2, workers=1)
    frames = read_capture(tmp_path / "m").sequences[0].frames
    for cam in ("cam0", "cam3"):
        stored = frames[2].image_paths[cam].read_bytes()
        assert stored[:2] == b"\xff\xd8" and stored in (videos / f"{cam}.avi").read_bytes()  # not re-encoded


def test_other_codecs_are_decoded_and_a_cut_video_is_refused(rig, tmp_path: Path) -> None:
    videos = tmp_path / "videos"
    videos.mkdir()
    for k, cam in enumerate(rig):
        writer = cv2.VideoWriter(str(videos / f"{cam.name}.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 30.0,
                                 (cam.width, cam.height))
        if not writer.isOpened():
            pytest.skip("this OpenCV build cannot write FFV1")
        for i in range(4):
            writer.write(cv2.cvtColor(_frame(k, i, cam.height, cam.width), cv2.COLOR_RGB2BGR))
        writer.release()
    assemble_capture(rig, tmp_path / "f", videos=videos, workers=1)
    cap = read_capture(tmp_path / "f")
    image = load_frame_images(cap.sequences[0].frames[3], cap.cameras)["cam1"]
    assert np.abs(image.astype(int) - _frame(1, 3, rig[1].height, rig[1].width)).mean() < 2.0  # lossless + q92

    (tmp_path / "cut").mkdir()
    mjpeg, _ = _write_sources(tmp_path / "cut", rig, {})
    data = (mjpeg / "cam2.avi").read_bytes()
    (mjpeg / "cam2.avi").write_bytes(data[: len(data) * 2 // 3])  # the header still counts every frame
    with pytest.raises(CaptureError, match=r"cam2.avi: camera 'cam2': (the video ends|frame \d+ is not a complete)"):
        assemble_capture(rig, tmp_path / "x", videos=mjpeg, workers=1)
    assert not (tmp_path / "x").exists()


def test_the_key_colour_is_a_per_capture_setting(rig, tmp_path: Path) -> None:
    """A blue screen keyed with --key-color: the hand square is the foreground; keyed with the default green
    the blue screen stays foreground (the colour is used, not assumed); a malformed colour is refused."""
    blue = (30, 60, 200)  # RGB
    images = tmp_path / "blue"
    for k, cam in enumerate(rig):
        (images / cam.name).mkdir(parents=True)
        for i in range(2):
            rgb = np.zeros((cam.height, cam.width, 3), np.uint8)
            rgb[:] = blue
            x, y = 4 + 8 * i, 10 + 3 * k
            rgb[y:y + 20, x:x + 16] = (230, 200, 170)
            cv2.imwrite(str(images / cam.name / f"{i}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    save_calibration(rig, tmp_path / "calibration.json")
    runner = CliRunner()
    base = ["capture", "assemble", "--calibration", str(tmp_path / "calibration.json"), "--images", str(images),
            "--green-screen", "--workers", "1"]
    result = runner.invoke(app, [*base, "--key-color", "#1e3cc8", "--out", str(tmp_path / "b")])
    assert result.exit_code == 0, result.output
    seq = read_capture(tmp_path / "b").sequences[0]
    assert seq.chroma_key == ChromaKey(color="#1e3cc8").to_dict()
    mask = load_frame_masks(seq.frames[1])["cam3"]
    expected = np.zeros_like(mask)
    expected[10 + 9:10 + 9 + 20, 12:12 + 16] = True
    assert (mask != expected).mean() < 0.02
    assert (tmp_path / "b" / "previews" / "chroma_key_seq000.jpg").is_file()
    result = runner.invoke(app, [*base, "--out", str(tmp_path / "g")])  # the default key colour: green
    assert result.exit_code == 0, result.output
    assert load_frame_masks(read_capture(tmp_path / "g").sequences[0].frames[1])["cam3"].mean() > 0.95
    result = runner.invoke(app, [*base, "--key-color", "blue", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "field 'color' must be a hex colour" in result.output
    assert not (tmp_path / "x").exists()
