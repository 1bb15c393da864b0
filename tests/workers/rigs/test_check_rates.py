"""The calibration check's blame rates on synthetic rigs with a detector's faults (tests/support/hand_views.py):
3-8 cameras of the default rig at sensor resolution, a hand moving over 20 frames within 0.3 m of the rig's
centre, 5-15 px Gaussian noise per camera, 5 % far-off keypoints and 2 % wrong views. 100 seeded rigs per case;
the rates are printed in the assertion message (and recorded in docs/calibration.md)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.hand_views import hand_track, moved, observe, rotated, swapped
from workers.geometry.rig import default_rig
from workers.rigs.check import check_keypoints, format_report

TRIALS = 100
REQUIRED = 0.95


def _trial(case: str, seed: int) -> tuple[list[str], list[str], str]:
    """One seeded rig: (the cameras that should be flagged, those flagged, the verdict)."""
    rng = np.random.default_rng(10_000 + seed)
    C = int(rng.integers(3, 9))
    rig = default_rig(None, seed=seed)
    true = [rig[i] for i in sorted(rng.choice(len(rig), C, replace=False))]
    keypoints, visible = observe(hand_track(rng), true, rng)
    bad = int(rng.integers(C))
    calibration, want = list(true), [true[bad].name]
    if case == "rotated":
        calibration[bad] = rotated(true[bad], rng.uniform(1.0, 3.0), rng.normal(size=3))
    elif case == "moved":
        direction = rng.normal(size=3)
        calibration[bad] = moved(true[bad], 0.05 * direction / np.linalg.norm(direction))
    elif case == "swapped":
        other = int((bad + rng.integers(1, C)) % C)
        calibration, want = swapped(true, bad, other), sorted([true[bad].name, true[other].name])
    else:
        want = []
    report = check_keypoints(calibration, keypoints, visible, source="synthetic")
    assert "nan" not in format_report(report).lower()
    return want, sorted(report.flagged), report.verdict


@pytest.mark.slow  # 100 rigs per case: ~70 s a case on a lightly loaded core
@pytest.mark.parametrize("case", ["clean", "rotated", "swapped", "moved"])
def test_the_right_camera_is_blamed(case: str) -> None:
    results = [_trial(case, seed) for seed in range(TRIALS)]
    right = sum(want == flagged for want, flagged, _ in results)
    verdicts: dict[str, int] = {}
    for _, _, verdict in results:
        verdicts[verdict] = verdicts.get(verdict, 0) + 1
    rate = right / TRIALS
    wrong = sum(bool(flagged) and flagged != want for want, flagged, _ in results)
    message = f"{case}: right in {right}/{TRIALS} = {rate:.0%}, a wrong camera in {wrong} (verdicts {verdicts})"
    print(message)
    assert rate >= REQUIRED, message
    wrong = [(want, flagged) for want, flagged, _ in results if flagged and flagged != want]
    assert len(wrong) <= TRIALS * (1 - REQUIRED), f"{message}; a wrong camera blamed: {wrong}"
