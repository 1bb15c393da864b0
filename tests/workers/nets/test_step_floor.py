"""A step floor holds training open past its seconds budget (a machine without native bfloat16 learns as much),
but never past MIN_STEPS_MAX_BUDGETS budgets; the rounds give HandSegNet cpu-small's floor."""

from __future__ import annotations

from dataclasses import replace

import pytest

from workers.nets import train as train_module
from workers.nets.configs import HandSegNetConfig, get_config
from workers.nets.data import build_handseg_dataset
from workers.nets.train import MIN_STEPS_MAX_BUDGETS, schedule_fraction, train_handsegnet


def test_without_a_floor_the_budget_or_max_steps_ends_training() -> None:
    assert schedule_fraction(45.0, 10, 90.0) == 0.5
    assert schedule_fraction(90.0, 10, 90.0) == 1.0
    assert schedule_fraction(10.0, 50, 90.0, max_steps=50) == 1.0
    assert schedule_fraction(0.0, 0, 90.0, max_steps=0) == 1.0  # no step at all


def test_a_floor_holds_training_open_until_its_steps() -> None:
    # Past the budget with fewer steps than the floor: not done, the schedule follows the steps.
    assert schedule_fraction(100.0, 640, 90.0, min_steps=1280) == pytest.approx(
        max(0.5, 100 / (MIN_STEPS_MAX_BUDGETS * 90)))
    assert schedule_fraction(120.0, 1280, 90.0, min_steps=1280) == 1.0
    # Steps past the floor before the budget: the budget ends it, as without a floor.
    assert schedule_fraction(45.0, 2000, 90.0, min_steps=1280) == 0.5
    # Never past MIN_STEPS_MAX_BUDGETS budgets, whatever the steps (a loaded machine).
    assert schedule_fraction(MIN_STEPS_MAX_BUDGETS * 90.0, 10, 90.0, min_steps=1280) == 1.0
    # max_steps still comes first.
    assert schedule_fraction(100.0, 700, 90.0, min_steps=1280, max_steps=700) == 1.0


def test_training_makes_the_floor_s_steps_past_a_spent_budget(tiny_capture, tiny_frames, tmp_path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    # A budget spent before the first step and no cap in reach: the floor alone decides, so the count is exact.
    monkeypatch.setattr(train_module, "MIN_STEPS_MAX_BUDGETS", 1e12)
    config = replace(get_config("tiny").handsegnet, cut_paste_prob=0.0)
    dataset = build_handseg_dataset(tiny_capture, tiny_frames)
    seen: list[float] = []
    result = train_handsegnet(dataset, config, budget_s=1e-9, checkpoint_dir=tmp_path, min_steps=3,
                              progress=lambda p: seen.append(p.fraction), resume=False)
    assert result.metadata["steps"] == 3
    assert seen == pytest.approx([1 / 3, 2 / 3, 1.0])
    without = train_handsegnet(dataset, config, budget_s=1e-9, checkpoint_dir=tmp_path / "none", resume=False)
    assert without.metadata["steps"] == 0


def test_bad_floors_are_refused(tiny_capture, tiny_frames, tmp_path) -> None:
    dataset = build_handseg_dataset(tiny_capture, tiny_frames)
    with pytest.raises(ValueError, match="min_steps"):
        train_handsegnet(dataset, get_config("tiny"), budget_s=1.0, checkpoint_dir=tmp_path, min_steps=0)
    with pytest.raises(ValueError, match="round_min_steps"):
        HandSegNetConfig(round_min_steps=-5)


def test_cpu_small_rounds_give_handsegnet_a_floor_and_tiny_none() -> None:
    for name in ("cpu-small", "cpu-small-detector"):
        assert get_config(name).handsegnet.round_min_steps == 1650
    assert get_config("tiny").handsegnet.round_min_steps is None
