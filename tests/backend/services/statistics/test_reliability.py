"""The reliability binning on hand-made values (services.statistics.reliability.reliability_bins)."""

from __future__ import annotations

import numpy as np
import pytest

from backend.services.statistics.reliability import reliability_bins


def test_bins_count_and_average_the_errors_by_confidence():
    out = reliability_bins(np.array([0.05, 0.15, 0.95, 1.0, np.nan, 0.5]), np.array([10, 8, 1, 3, 5, np.inf]), 10)
    assert out["counts"] == [1, 1, 0, 0, 0, 0, 0, 0, 0, 2] and out["n"] == 4  # non-finite pairs are left out
    assert out["mean_error"] == [10.0, 8.0, None, None, None, None, None, None, None, 2.0]
    assert out["edges"][0] == 0.0 and out["edges"][-1] == 1.0 and len(out["edges"]) == 11


def test_out_of_range_confidences_are_clipped_and_bad_arguments_refused():
    out = reliability_bins(np.array([-0.5, 1.5]), np.array([1.0, 2.0]), 2)
    assert out["counts"] == [1, 1] and out["mean_error"] == [1.0, 2.0]
    with pytest.raises(ValueError, match=r"bins must be in 1\.\.50"):
        reliability_bins(np.zeros(1), np.zeros(1), 0)
    with pytest.raises(ValueError, match="differ in length"):
        reliability_bins(np.zeros(2), np.zeros(3), 4)
