"""Benchmark metrics as FreiHAND's official evaluation computes them (docs/evaluation.md)."""

from workers.evaluation.alignment import Similarity, align_w_scale, apply_similarity, similarity_transform
from workers.evaluation.freihand_files import (
    EvaluationInputError,
    PointSets,
    check_pair,
    load_ground_truth,
    load_predictions,
)
from workers.evaluation.metrics import (
    F_THRESHOLDS_M,
    FreiHANDScores,
    FScore,
    PckSummary,
    SampleErrors,
    evaluate,
    fscore,
    pck_thresholds_m,
    sample_errors,
    summarise_errors,
)

__all__ = [
    "F_THRESHOLDS_M",
    "EvaluationInputError",
    "FScore",
    "FreiHANDScores",
    "PckSummary",
    "PointSets",
    "SampleErrors",
    "Similarity",
    "align_w_scale",
    "apply_similarity",
    "check_pair",
    "evaluate",
    "fscore",
    "load_ground_truth",
    "load_predictions",
    "pck_thresholds_m",
    "sample_errors",
    "similarity_transform",
    "summarise_errors",
]
