"""Pre-annotation's failure path names a wrong calibration scale: a found hand that the lift (metric thresholds)
cannot lift, or lifts to no human size, is reported with the factor that would fix the rig."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from workers.detector.lifting import lift
from workers.detector.types import ViewKeypoints
from workers.geometry.projection import project_points
from workers.geometry.rig import default_rig
from workers.handmodel.layer import HandLayer
from workers.handmodel.loading import load_hand_model
from workers.rigs.hand_scale import estimate_hand_scale
from workers.tasks.preannotate import _scale_problem


def _views(rig) -> list[ViewKeypoints]:
    torch.manual_seed(0)
    with torch.no_grad():
        hand = HandLayer(load_hand_model(None))(pose=torch.randn(1, 45) * 0.3).keypoints[0].numpy().astype(float)
    pixels, _ = project_points(hand, rig)
    views = []
    for xy in pixels:
        box = np.array([xy[:, 0].min(), xy[:, 1].min(), np.ptp(xy[:, 0]), np.ptp(xy[:, 1])])
        views.append(ViewKeypoints(xy, np.full(21, 0.9), 0.95, "right", box, 0.0))
    return views


def test_a_rig_20_times_too_large_fails_the_lift_and_the_message_gives_the_factor() -> None:
    rig = default_rig(None)
    views = _views(rig)
    wrong = [replace(c, t=c.t * 20.0) for c in rig]  # board squares of 5 cm read as metres
    lifted = lift(views, wrong)
    assert np.isfinite(lifted.points_world).all(axis=1).sum() < 6
    problem = _scale_problem(lifted, wrong)
    assert problem.startswith("; the triangulated hand measures")
    factor = float(problem.split("--scale set to ")[1].split(" ")[0])
    assert factor == pytest.approx(1 / 20.0, rel=0.04)
    right = lift(views, rig)
    assert np.isfinite(right.points_world).all(axis=1).all() and _scale_problem(right, rig) == ""


def test_a_rig_100_times_too_small_lifts_a_hand_of_no_human_size() -> None:
    rig = default_rig(None)
    views = _views(rig)
    wrong = [replace(c, t=c.t * 0.01) for c in rig]  # centimetres read as metres
    lifted = lift(views, wrong)
    assert np.isfinite(lifted.points_world).all(axis=1).all()  # the lift's thresholds cannot tell
    size = estimate_hand_scale(lifted.points_world[None])
    assert size.verdict == "too small" and size.factor == pytest.approx(100.0, rel=0.04)
    assert "the hand is too small by" in _scale_problem(lifted, wrong)
