"""workers/capture/working.py: the working resolution's cameras, copies and the way back to full pixels."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from workers.capture.working import (
    derived_key,
    load_working_images,
    mask_to_working,
    probabilities_to_full,
    to_full_px,
    working_camera,
    working_cameras,
    working_image,
    working_jpeg,
    working_mask_png,
    working_size,
)
from workers.geometry.camera import Camera
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig


def _rig_2048():
    """The default rig as 2048 x 1536 px cameras (3 Mpx, the size of the import benchmark's images)."""
    cameras = []
    for cam in default_rig(None):
        big = cam.scaled(2048)
        K = big.K.copy()
        K[1, 2] = 767.5
        cameras.append(replace(big, height=1536, K=K))
    cameras[3] = replace(cameras[3], dist=np.array([-0.12, 0.05, 1e-3, -2e-3, 0.01]))  # distortion kept as is
    return cameras


def test_working_pixels_map_onto_full_resolution_projections() -> None:
    full = _rig_2048()
    small = working_cameras(full, 512)
    assert all((c.width, c.height) == (512, 384) for c in small)
    points = np.random.default_rng(3).normal(0.0, 0.08, (50, 3))
    px_full, _ = project_points(points, full)
    px_small, _ = project_points(points, list(small))
    for c, (s, f) in enumerate(zip(small, full, strict=True)):
        np.testing.assert_allclose(to_full_px(px_small[c], s, f), px_full[c], rtol=0, atol=1e-9)
    assert not np.allclose(px_small, px_full)  # the working pixels are not full-resolution pixels


def test_sizes_follow_camera_scaled_and_narrow_cameras_stay() -> None:
    cam = default_rig(None)[0]
    for full_w, full_h in ((2048, 1536), (1999, 1001), (4096, 2160)):
        scaled = replace(cam, width=full_w, height=full_h).scaled(640)
        assert working_size(full_w, full_h, 640) == (scaled.width, scaled.height)
    narrow = cam.scaled(320)
    assert working_camera(narrow, 640) is narrow and working_camera(narrow, None) is narrow
    with pytest.raises(ValueError, match="sizes must be positive"):
        working_size(0, 10, 5)
    assert derived_key("images/p1/seq000/cam0/000003.png", 512) == "derived-v2/w512/images/p1/seq000/cam0/000003.jpg"
    assert derived_key("masks/chroma/7.png", 512, ".png") == "derived-v2/w512/masks/chroma/7.png"


def test_copies_are_area_averaged_and_masks_come_back_to_full_size(tmp_path) -> None:
    full = _rig_2048()[0]
    small = full.scaled(512)
    image = np.zeros((full.height, full.width, 3), np.uint8)
    image[400:800, 1000:1400] = 200  # a grey square
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    copy = working_jpeg(data.tobytes(), (full.width, full.height), (512, 384), "x")
    copy = cv2.imdecode(np.frombuffer(copy, np.uint8), cv2.IMREAD_COLOR)
    assert copy.shape == (384, 512, 3)
    assert np.abs(copy[102:198, 252:348].astype(int) - 200).max() < 12  # the square, a quarter the size
    assert copy[:90].max() < 12
    mask = np.zeros((full.height, full.width), bool)
    mask[400:800, 1000:1400] = True
    ok, png = cv2.imencode(".png", mask.astype(np.uint8) * 255)
    small_mask = cv2.imdecode(np.frombuffer(working_mask_png(png.tobytes(), (512, 384), "m"), np.uint8), 0) >= 128
    assert small_mask.shape == (384, 512) and (small_mask == mask_to_working(mask, small)).all()
    assert small_mask.sum() == 100 * 100
    back = probabilities_to_full(small_mask.astype(np.float32), full) > 0.5
    assert back.shape == (full.height, full.width) and (back != mask).mean() < 1e-3
    (tmp_path / "cam0.jpg").write_bytes(data.tobytes())
    rgb = load_working_images({"cam0": tmp_path / "cam0.jpg"}, [full], [small])["cam0"]
    assert rgb.shape == (384, 512, 3) and tuple(rgb[150, 300]) == tuple(copy[150, 300][::-1])
    with pytest.raises(ValueError, match=r"image 'bad' cannot be decoded"):
        working_jpeg(b"not a jpeg", (full.width, full.height), (512, 384), "bad")


def _camera(width: int, height: int) -> Camera:
    """A camera of `width` x `height` px with its principal point off centre and some distortion."""
    K = np.array([[0.9 * width, 0.0, (width - 1) / 2 + 3.3], [0.0, 0.9 * width, (height - 1) / 2 - 2.7], [0, 0, 1]])
    return Camera("cam", width, height, K, np.array([-0.05, 0.02, 0.0, 0.0, 0.0]), np.eye(3), np.zeros(3))


def _blob(width: int, height: int, centre: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W, 3) uint8 grey Gaussian blob centred on the sub-pixel `centre` (x, y), pixel centres at integers."""
    x = np.arange(width) - centre[0]
    y = np.arange(height) - centre[1]
    blob = 250.0 * np.exp(-0.5 * (y[:, None] ** 2 + x[None, :] ** 2) / sigma**2)
    return np.repeat(np.round(blob).astype(np.uint8)[:, :, None], 3, axis=2)


def _centroid(image: np.ndarray, near: np.ndarray, radius: int) -> np.ndarray:
    """(x, y) intensity centroid of a (h, w, 3) image within `radius` px of `near`."""
    grey = image[:, :, 1].astype(np.float64)
    x0, y0 = (int(np.rint(c)) for c in near)
    window = grey[y0 - radius:y0 + radius + 1, x0 - radius:x0 + radius + 1]
    ys, xs = np.mgrid[y0 - radius:y0 + radius + 1, x0 - radius:x0 + radius + 1]
    return np.array([(window * xs).sum(), (window * ys).sum()]) / window.sum()


@pytest.mark.parametrize(("full_size", "width"), [((2050, 1538), 250), ((2448, 2048), 640), ((2704, 2028), 320),
                                                  ((1999, 1001), 640)])
@pytest.mark.parametrize("ext", [".jpg", ".png"])
def test_working_copy_content_sits_where_the_working_camera_projects(full_size, width, ext) -> None:
    """A sub-pixel blob at a keypoint's full-resolution projection (near the bottom-right corner, where a scale
    error is largest) lands in the working copy at the working camera's projection of that keypoint."""
    full = _camera(*full_size)
    small = working_camera(full, width)
    assert (small.width, small.height) == working_size(*full_size, width)
    ray = np.linalg.solve(full.K, [0.88 * full.width, 0.9 * full.height, 1.0])
    point = ray[None] * 0.7  # metres, in front of the camera
    px_full = project_points(point, [full])[0][0, 0]
    px_small = project_points(point, [small])[0][0, 0]
    sx, sy = small.width / full.width, small.height / full.height  # each axis as the resized image has it
    np.testing.assert_allclose(px_small, (px_full + 0.5) * [sx, sy] - 0.5, rtol=0, atol=1e-9)
    np.testing.assert_allclose(to_full_px(px_small, small, full), px_full, rtol=0, atol=1e-9)
    sigma = 4.0 / sx  # 4 working px
    ok, data = cv2.imencode(ext, _blob(*full_size, px_full, sigma), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    copy = working_image(data.tobytes(), full_size, (small.width, small.height), "blob")
    assert copy.shape == (small.height, small.width, 3)
    np.testing.assert_allclose(_centroid(copy, px_small, 16), px_small, rtol=0, atol=0.05)


def test_png_copies_are_area_averaged_not_subsampled() -> None:
    """Fine stripes (period 3 px) in a PNG average to a flat grey in the working copy: OpenCV's reduced PNG
    decode would subsample them (INTER_LINEAR_EXACT) into coarse stripes."""
    stripes = np.zeros((1536, 2048, 3), np.uint8)
    stripes[:, ::3] = 255
    ok, data = cv2.imencode(".png", stripes)
    assert ok
    copy = working_image(data.tobytes(), (2048, 1536), (250, 188), "stripes")
    assert copy.shape == (188, 250, 3)
    inner = copy[2:-2, 2:-2].astype(int)
    assert abs(inner.mean() - 85) < 1
    assert np.abs(inner - 85).max() <= 255 * 250 / 2048  # a window of 8.2 px holds 2 or 3 stripes, partly
