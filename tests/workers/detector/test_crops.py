"""A crop's coordinates map back to image pixels exactly, under rotation and mirroring."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.detector.crops import Crop, crop_from_mask, upright_rotation
from workers.detector.view import refined_crop

ROTATIONS = (0.0, 0.3, math.pi / 2, 2.5, math.pi, -1.1)


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("rotation", ROTATIONS)
def test_round_trip_is_exact(rotation: float, mirrored: bool) -> None:
    crop = Crop((123.4, 87.9), 61.3, rotation, mirrored)
    points = np.random.default_rng(0).uniform(-20, 250, (50, 2))
    np.testing.assert_allclose(crop.to_image(crop.to_crop(points)), points, atol=1e-9)
    # The window's centre is the crop's centre, its corners lie side_px from each other.
    np.testing.assert_allclose(crop.to_image(np.array([112.0, 112.0])), crop.center_px, atol=1e-9)
    corners = crop.to_image(np.array([[0.0, 0.0], [224.0, 0.0]]))
    assert np.linalg.norm(corners[1] - corners[0]) == pytest.approx(61.3)


def _blob(shape: tuple[int, int], center: np.ndarray, sigma: float) -> np.ndarray:
    ys, xs = np.mgrid[: shape[0], : shape[1]]
    value = np.exp(-((xs - center[0]) ** 2 + (ys - center[1]) ** 2) / (2 * sigma**2))
    return np.repeat((255 * value).astype(np.uint8)[..., None], 3, axis=2)


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("rotation", ROTATIONS)
def test_sampled_pixels_map_back_to_where_they_were(rotation: float, mirrored: bool) -> None:
    """A bright blob at a known image point appears in the crop where `to_crop` says; its centroid maps back."""
    target = np.array([141.3, 96.7])
    image = _blob((240, 320), target, sigma=3.0)
    crop = Crop((130.2, 101.5), 48.0, rotation, mirrored)
    patch = crop.extract(image)[..., 0].astype(np.float64)
    ys, xs = np.mgrid[:224, :224]
    weight = patch**4  # sharpen: the centroid of the peak, not of the blur's tails
    centroid_crop = np.array([(weight * xs).sum(), (weight * ys).sum()]) / weight.sum() + 0.5  # edge-based
    np.testing.assert_allclose(centroid_crop, crop.to_crop(target), atol=0.35)
    np.testing.assert_allclose(crop.to_image(centroid_crop), target, atol=0.1)


def test_mirroring_flips_left_right_only() -> None:
    plain, mirrored = Crop((50.0, 50.0), 20.0, 0.4), Crop((50.0, 50.0), 20.0, 0.4, True)
    p = np.array([60.0, 47.0])
    a, b = plain.to_crop(p), mirrored.to_crop(p)
    assert b[0] == pytest.approx(224 - a[0]) and b[1] == pytest.approx(a[1])


@pytest.mark.parametrize("angle_deg", [0, 37, 90, 180, -120])
def test_refined_crop_shows_the_hand_upright(angle_deg: float) -> None:
    """wrist -> middle MCP points straight up in the refined crop, whatever its direction in the image."""
    a = math.radians(angle_deg)
    direction = np.array([math.sin(a), -math.cos(a)])  # angle_deg clockwise from "up" on screen
    keypoints = np.tile([200.0, 150.0], (21, 1)) + np.random.default_rng(1).normal(0, 15, (21, 2))
    keypoints[0] = [200.0, 150.0]
    keypoints[9] = keypoints[0] + 30 * direction
    for mirrored in (False, True):
        crop = refined_crop(keypoints, mirrored)
        wrist, mcp = crop.to_crop(keypoints[[0, 9]])
        step = mcp - wrist
        assert step[1] < 0 and abs(step[0]) < 1e-6 * abs(step[1])
        inside = crop.to_crop(keypoints)
        assert np.all((inside >= 0) & (inside <= 224))
    assert upright_rotation(keypoints[0], keypoints[0] + [0, -1]) == pytest.approx(0.0)


def test_crop_from_mask_takes_the_largest_blob() -> None:
    mask = np.zeros((100, 100), bool)
    mask[10:30, 40:50] = True  # 200 px
    mask[80:82, 5:7] = True  # a speck
    x, y, side = crop_from_mask(mask, 1.5)
    assert (x, y) == pytest.approx((44.5, 19.5)) and side == pytest.approx(30.0)
    assert crop_from_mask(np.zeros((10, 10), bool), 1.5) is None


def test_crop_refuses_non_finite_windows() -> None:
    with pytest.raises(ValueError):
        Crop((np.nan, 1.0), 10.0)
    with pytest.raises(ValueError):
        Crop((1.0, 1.0), 0.0)
