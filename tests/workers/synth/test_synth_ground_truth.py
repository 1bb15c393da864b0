"""Synthetic ground truth is self-consistent: masks vs rasterised vertices, 2D vs 3D keypoints,
parameters vs the hand layer, visibility vs occlusion, chroma key vs the rendered parts."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from workers.geometry import project_points
from workers.rendering import model_mask, rasterize
from workers.synth.frame import FOREARM, HAND, OBJECT


def _frames(rendered):
    return [(i, f) for i, frames in rendered.items() for f in frames]


def test_plans_cover_train_object_and_evaluation(renderer):
    kinds = [(p.split, p.green_screen, p.held_object is not None) for p in renderer.plans]
    assert kinds == [("train", True, False), ("train", True, True), ("evaluation", False, False)]


def test_keypoints_2d_are_the_projected_3d_keypoints(renderer, rendered):
    for _, frame in _frames(rendered):
        gt = frame.ground_truth
        pixels, _ = project_points(gt.keypoints_3d, list(renderer.cameras))
        np.testing.assert_allclose(gt.keypoints_2d, pixels, atol=1e-6)
        assert gt.camera_names == tuple(c.name for c in renderer.cameras)


def test_parameters_reproduce_vertices_and_keypoints(renderer, rendered):
    from workers.handmodel import HandLayer

    layer = HandLayer(renderer.arrays, dtype=torch.float64)
    for _, frame in _frames(rendered):
        gt = frame.ground_truth
        t = lambda a: torch.as_tensor(a)[None]  # noqa: E731
        out = layer(t(gt.betas), t(gt.pose), t(gt.global_orient), t(gt.transl))
        np.testing.assert_allclose(out.vertices[0].numpy(), gt.vertices, atol=1e-9)
        np.testing.assert_allclose(out.keypoints[0].numpy(), gt.keypoints_3d, atol=1e-9)
        assert np.all(np.abs(gt.betas) <= 2.0)


def test_hand_mask_is_the_rasterised_hand_minus_what_covers_it(renderer, rendered):
    """GT hand mask == silhouette of the projected hand vertices where no forearm / object is nearer,
    computed here independently, one part at a time."""
    cams = list(renderer.cameras)
    for _, frame in _frames(rendered):
        gt, parts = frame.ground_truth, frame.parts
        hand = rasterize(parts[HAND].vertices, parts[HAND].faces, cams, with_bary=False)
        others = [rasterize(p.vertices, p.faces, cams, with_bary=False) for p in parts[1:]]
        for c, cam in enumerate(cams):
            silhouette = model_mask(gt.vertices, renderer.arrays.faces, cam)
            assert np.array_equal(silhouette, hand[c].mask)
            nearest_other = np.min([o[c].depth_m for o in others], axis=0)
            expected = hand[c].mask & (hand[c].depth_m < nearest_other)
            got = gt.hand_masks[cam.name]
            assert not (got & ~silhouette).any()  # never outside the hand's own silhouette
            # Equal up to depth ties along the wrist seam, where the forearm starts inside the hand.
            assert (got ^ expected).sum() <= max(3, 0.01 * expected.sum()), cam.name


def test_visible_keypoints_sit_on_the_hand(renderer, rendered):
    for _, frame in _frames(rendered):
        gt = frame.ground_truth
        for c, cam in enumerate(renderer.cameras):
            own = np.isin(frame.part_ids[cam.name], (HAND, FOREARM))
            near_own = cv2.dilate(own.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            for k in np.flatnonzero(gt.visibility[c]):
                u, v = np.rint(gt.keypoints_2d[c, k]).astype(int)
                assert near_own[v, u], (cam.name, k)
        assert 0.2 < gt.visibility.mean() < 0.95  # occlusion happens, but most views see something


def test_keypoints_behind_the_object_are_invisible(renderer, rendered):
    """Where the object (rasterised on its own) is the nearest surface at a keypoint's pixel and lies in
    front of the keypoint, the keypoint is marked invisible in that view."""
    frames = rendered[1]  # holds an object
    cams = list(renderer.cameras)
    hidden = 0
    for frame in frames:
        gt = frame.ground_truth
        _, depth = project_points(gt.keypoints_3d, cams)
        obj = rasterize(frame.parts[OBJECT].vertices, frame.parts[OBJECT].faces, cams, with_bary=False)
        own = [rasterize(p.vertices, p.faces, cams, with_bary=False) for p in frame.parts[:OBJECT]]
        for c, cam in enumerate(cams):
            for k in range(21):
                u, v = np.rint(gt.keypoints_2d[c, k]).astype(int)
                if not (0 <= u < cam.width and 0 <= v < cam.height):
                    continue
                z_obj = obj[c].depth_m[v, u]
                if z_obj < depth[c, k] - 0.005 and z_obj < min(o[c].depth_m[v, u] for o in own):
                    hidden += 1
                    assert not gt.visibility[c, k], (cam.name, k)
    assert hidden > 0, "the object should hide some keypoint in some view"


def test_chroma_mask_covers_hand_forearm_and_object_but_not_the_screen(renderer, rendered):
    covered = {"hand": 0, "forearm": 0, "object": 0}
    total = dict.fromkeys(covered, 0)
    for index in (0, 1):
        for frame in rendered[index]:
            assert frame.chroma_masks is not None
            for cam in renderer.cameras:
                chroma, parts = frame.chroma_masks[cam.name], frame.part_ids[cam.name]
                # Inside the silhouette (away from anti-aliased, spilled edges) nothing is keyed out.
                inner = cv2.erode((parts >= 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
                assert chroma[inner].all(), cam.name
                assert (chroma & (parts < 0)).sum() <= 0.002 * (parts < 0).sum()  # the screen is keyed
                for name, mask in (("hand", frame.ground_truth.hand_masks[cam.name]),
                                   ("forearm", parts == FOREARM), ("object", parts == OBJECT)):
                    covered[name] += (chroma & mask).sum()
                    total[name] += mask.sum()
    # At 160 px a large share of the hand's pixels are edge pixels, which keying may lose.
    assert covered["hand"] >= 0.75 * total["hand"]
    assert covered["forearm"] >= 0.75 * total["forearm"] and covered["forearm"] > covered["hand"]
    assert covered["object"] >= 0.75 * total["object"] > 0
    assert rendered[2][0].chroma_masks is None  # evaluation: no green screen, no chroma key


def test_forearm_leaves_the_picture(renderer, rendered):
    for _, frame in _frames(rendered):
        for cam in renderer.cameras:
            forearm = frame.part_ids[cam.name] == FOREARM
            if forearm.any():
                border = forearm[0].any() | forearm[-1].any() | forearm[:, 0].any() | forearm[:, -1].any()
                assert border, cam.name


def test_backgrounds_differ_between_train_and_evaluation(rendered):
    train = rendered[0][0].images["cam0"].reshape(-1, 3).mean(0)
    evaluation = rendered[2][0].images["cam0"].reshape(-1, 3).mean(0)
    assert train[1] > train[0] + 40 and train[1] > train[2] + 40  # green screen
    assert not (evaluation[1] > evaluation[0] + 40 and evaluation[1] > evaluation[2] + 40)


@pytest.mark.parametrize("index", [0, 2])
def test_rendering_is_deterministic(renderer, rendered, index):
    from workers.synth.generator import FrameRenderer

    again = FrameRenderer(renderer.config).render(index, 1, 2)[0]
    assert np.array_equal(again.images["cam4"], rendered[index][1].images["cam4"])
