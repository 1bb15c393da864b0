"""A fit's recorded 2D residuals keep points the annotator accepted from proposals apart from points placed by
hand: a fit lands near the proposals it was given, so a mean over both would look better than the evidence."""

from __future__ import annotations

import numpy as np

from workers.fitting.result import FitDiagnostics


def _diagnostics(accepted: np.ndarray | None) -> FitDiagnostics:
    residual = np.full((3, 21), np.nan)  # (C, 21) px
    residual[0, [0, 4, 8, 12, 16, 20]] = [3.0, 4.0, 5.0, 4.0, 3.0, 5.0]  # placed by hand
    residual[1, [0, 4, 8, 12, 16, 20]] = 0.5  # accepted proposals: the fit sits on them
    return FitDiagnostics(iou_per_view=np.full(3, np.nan), residual_2d_px=residual, residual_3d_mm=np.full(21, np.nan),
                          loss_terms={}, iterations=1, seconds=0.0, accepted_2d=accepted)


def test_the_mean_residual_is_over_points_placed_by_hand_and_accepted_proposals_are_apart() -> None:
    accepted = np.zeros((3, 21), bool)
    accepted[1] = True  # the whole view accepted (its unclicked keypoints have no residual: not counted)
    out = _diagnostics(accepted).to_dict()
    assert out["mean_residual_2d_px"] == 4.0  # not 2.25, the mean over both
    assert out["residual_2d_by_origin"] == {"clicked": {"n": 6, "mean_px": 4.0, "max_px": 5.0},
                                            "accepted": {"n": 6, "mean_px": 0.5, "max_px": 0.5}}
    assert out["accepted_2d"] == [[1, k] for k in (0, 4, 8, 12, 16, 20)]


def test_without_origins_every_point_counts_as_placed_by_hand() -> None:
    out = _diagnostics(None).to_dict()
    assert out["residual_2d_by_origin"]["clicked"]["n"] == 12 and out["residual_2d_by_origin"]["accepted"]["n"] == 0
    assert out["mean_residual_2d_px"] == 2.25 and out["accepted_2d"] == []


def test_only_accepted_proposals_leave_no_mean_to_flatter_the_fit() -> None:
    accepted = np.ones((3, 21), bool)
    out = _diagnostics(accepted).to_dict()
    assert out["mean_residual_2d_px"] is None and out["residual_2d_by_origin"]["accepted"]["n"] == 12
