"""A fit's recorded 2D residuals keep points the annotator accepted from proposals apart from points placed by
hand: a fit lands near the proposals it was given, so a mean over both would look better than the evidence."""

from __future__ import annotations

import numpy as np

from workers.fitting.result import FitDiagnostics


def _diagnostics(accepted: np.ndarray | None, points_source: str = "annotation") -> FitDiagnostics:
    residual = np.full((3, 21), np.nan)  # (C, 21) px
    residual[0, [0, 4, 8, 12, 16, 20]] = [3.0, 4.0, 5.0, 4.0, 3.0, 5.0]  # placed by hand
    residual[1, [0, 4, 8, 12, 16, 20]] = 0.5  # accepted proposals: the fit sits on them
    return FitDiagnostics(iou_per_view=np.full(3, np.nan), residual_2d_px=residual, residual_3d_mm=np.full(21, np.nan),
                          loss_terms={}, iterations=1, seconds=0.0, accepted_2d=accepted,
                          points_source=points_source)


def test_the_mean_residual_is_over_points_placed_by_hand_and_accepted_proposals_are_apart() -> None:
    accepted = np.zeros((3, 21), bool)
    accepted[1] = True  # the whole view accepted (its unclicked keypoints have no residual: not counted)
    out = _diagnostics(accepted).to_dict()
    assert out["mean_residual_2d_px"] == 4.0 and out["mean_residual_2d_of"] == "clicked"  # not 2.25 over both
    assert out["residual_2d_by_origin"] == {"clicked": {"n": 6, "mean_px": 4.0, "max_px": 5.0},
                                            "accepted": {"n": 6, "mean_px": 0.5, "max_px": 0.5},
                                            "detector": {"n": 0, "mean_px": None, "max_px": None}}
    assert out["accepted_2d"] == [[1, k] for k in (0, 4, 8, 12, 16, 20)]


def test_without_origins_every_point_counts_as_placed_by_hand() -> None:
    out = _diagnostics(None).to_dict()
    assert out["residual_2d_by_origin"]["clicked"]["n"] == 12 and out["residual_2d_by_origin"]["accepted"]["n"] == 0
    assert out["mean_residual_2d_px"] == 2.25 and out["accepted_2d"] == []


def test_only_accepted_proposals_give_the_mean_and_say_so() -> None:
    accepted = np.ones((3, 21), bool)
    out = _diagnostics(accepted).to_dict()
    assert out["residual_2d_by_origin"]["clicked"]["n"] == 0 and out["residual_2d_by_origin"]["accepted"]["n"] == 12
    assert (out["mean_residual_2d_px"], out["mean_residual_2d_of"]) == (2.25, "accepted")


def test_a_detector_fit_reports_its_residuals_as_the_detectors_not_as_clicks() -> None:
    out = _diagnostics(None, points_source="detector").to_dict()
    assert out["residual_2d_by_origin"] == {"clicked": {"n": 0, "mean_px": None, "max_px": None},
                                            "accepted": {"n": 0, "mean_px": None, "max_px": None},
                                            "detector": {"n": 12, "mean_px": 2.25, "max_px": 5.0}}
    assert (out["mean_residual_2d_px"], out["mean_residual_2d_of"]) == (2.25, "detector")
    assert out["accepted_2d"] == []
