"""`bench sim`'s per-round rows: MVNet's error and the heuristic's counts by sequence kind, in the JSON rows and
in the line printed for people."""

from __future__ import annotations

from backend.bench.sim import by_kind_line, side_by_side_rows


def _round(index: int, heuristic: dict | None) -> dict:
    kinds = {"green_screen": {"predictions": 12, "keypoint_mm": 9.25, "keypoint_mm_median": 8.5, "auc": 0.81},
             "cluttered": {"predictions": 4, "keypoint_mm": 41.0, "keypoint_mm_median": 39.5, "auc": 0.22}}
    return {"index": index, "added": {"heuristic": 1, "manual": 2, "annotated": 3},
            "round_job": {"heuristic": heuristic} if heuristic else None, "mvnet_keypoint_mm": 17.2,
            "mvnet_keypoint_mm_median": 12.0, "mvnet_auc": 0.66, "mvnet_by_kind": kinds}


def test_rows_carry_mvnet_and_the_heuristic_by_sequence_kind():
    by_kind = {"green_screen": {"fits": 12, "evaluated": 12, "accepted": 3, "failures": {"mean confidence": 7}},
               "cluttered": {"fits": 6, "evaluated": 4, "accepted": 0,
                             "failures": {"mean IoU": 4, "max 3D distance": 2}}}
    row = side_by_side_rows({"rounds": [_round(1, {"evaluated": 16, "accepted": 3, "by_kind": by_kind})]})[0]
    assert row["heuristic_by_kind"] == by_kind and row["mvnet_by_kind"]["cluttered"]["keypoint_mm"] == 41.0
    assert (row["mvnet_keypoint_mm"], row["mvnet_keypoint_mm_median"], row["mvnet_auc"]) == (17.2, 12.0, 0.66)
    line = by_kind_line(row)
    assert ("green-screen: MVNet 9.2 mm mean, 8.5 mm median, AUC 0.81 over 12; heuristic accepted 3 of 12 "
            "evaluated (12 fits; failed: mean confidence 7)") in line
    assert ("cluttered: MVNet 41.0 mm mean, 39.5 mm median, AUC 0.22 over 4; heuristic accepted 0 of 4 evaluated "
            "(6 fits; failed: mean IoU 4, max 3D distance 2)") in line


def test_a_round_without_a_heuristic_summary_prints_mvnet_alone():
    row = side_by_side_rows({"rounds": [_round(0, None)]})[0]
    assert row["heuristic_by_kind"] is None
    assert "heuristic" not in by_kind_line(row) and "cluttered: MVNet 41.0 mm mean" in by_kind_line(row)


def test_the_cumulative_share_counts_every_round_s_acceptances_against_the_first_fitted_pool():
    """Round 2's own share falls when round 1 took the easy samples; the cumulative one (of round 1's fits) not."""
    rounds = [_round(0, None), _round(1, {"evaluated": 176, "accepted": 33}),
              _round(2, {"evaluated": 133, "accepted": 8})]
    rows = side_by_side_rows({"rounds": rounds})
    assert [r["heuristic_share"] for r in rows] == [None, 33 / 176, 8 / 133]
    assert [r["heuristic_share_cumulative"] for r in rows] == [None, 33 / 176, 41 / 176]


def test_with_round_0s_detector_heuristic_the_pool_is_every_sample_the_machine_fitted_once():
    """Round 0 pre-annotated 150 frames, the detector's heuristic took 60 and D_0 holds 90 of them; round 1 fitted the
    110 samples not in D_0. The pool is 90 + 110 (never round 0's 150 again), so the share is not overstated."""
    round0 = {**_round(0, None), "preannotation": {"result": {"heuristic": {"fits": 150, "evaluated": 150,
                                                                             "accepted": 60}}}, "dataset_size": 90}
    rounds = [round0, _round(1, {"evaluated": 110, "accepted": 20}), _round(2, {"evaluated": 80, "accepted": 10})]
    rows = side_by_side_rows({"rounds": rounds})
    assert [r["heuristic_share"] for r in rows] == [60 / 150, 20 / 110, 10 / 80]
    assert [r["heuristic_share_cumulative"] for r in rows] == [60 / 150, 80 / 200, 90 / 200]
