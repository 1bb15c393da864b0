"""Similarity (Procrustes with scale) alignment of a predicted point set to its ground truth.

Written to reproduce FreiHAND's official evaluation (`align_w_scale` in the benchmark's eval script):
both sets are centred and scaled to unit Frobenius norm, the orthogonal Procrustes problem is solved on
the normalised sets, and the prediction is mapped into the ground truth's frame. As in the official
script the orthogonal matrix is not restricted to rotations (a reflection is allowed when it fits
better); for hand-like point sets the optimum is a rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The official script adds this to both norms so that an all-zero prediction does not divide by zero.
NORM_EPS = 1e-8


@dataclass(frozen=True, eq=False)
class Similarity:
    """The map x -> (x - source_mean) @ R.T * scale + target_mean that aligns a source set to a target.

    Attributes:
        R: (3, 3) orthogonal matrix (applied as x @ R.T).
        scale: scale factor (the normalised Procrustes scale times the target's norm over the source's).
        source_mean: (3,) centroid of the source (prediction) set.
        target_mean: (3,) centroid of the target (ground truth) set.
    """

    R: np.ndarray
    scale: float
    source_mean: np.ndarray
    target_mean: np.ndarray


def _points(name: str, value: np.ndarray) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
        raise ValueError(f"{name} must have shape (N, 3) with N >= 1, got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} contains non-finite numbers")
    return array


def similarity_transform(target: np.ndarray, source: np.ndarray) -> Similarity:
    """The similarity that best maps `source` onto `target` (least squares, corresponding rows).

    Args:
        target: (N, 3) ground-truth points (any unit; the result is in the same unit).
        source: (N, 3) predicted points, same order.
    """
    target = _points("target", target)
    source = _points("source", source)
    if target.shape != source.shape:
        raise ValueError(f"target and source must have the same shape, got {target.shape} and {source.shape}")
    t_mean, s_mean = target.mean(0), source.mean(0)
    t_centred, s_centred = target - t_mean, source - s_mean
    t_norm = np.linalg.norm(t_centred) + NORM_EPS
    s_norm = np.linalg.norm(s_centred) + NORM_EPS
    # Orthogonal Procrustes on the normalised sets: R minimises |T R - S| (T, S normalised), from the SVD
    # of T^T S; its singular values sum to the optimal scale (what scipy.linalg.orthogonal_procrustes returns).
    U, singular, Vt = np.linalg.svd((t_centred / t_norm).T @ (s_centred / s_norm))
    R = U @ Vt
    return Similarity(R=R, scale=float(singular.sum()) * t_norm / s_norm, source_mean=s_mean, target_mean=t_mean)


def apply_similarity(points: np.ndarray, transform: Similarity) -> np.ndarray:
    """Map (N, 3) points with a similarity (each point: (x - source_mean) R^T scale + target_mean)."""
    points = _points("points", points)
    return (points - transform.source_mean) @ transform.R.T * transform.scale + transform.target_mean


def align_w_scale(target: np.ndarray, source: np.ndarray) -> np.ndarray:
    """`source` (N, 3) aligned to `target` (N, 3) by the best similarity (official `align_w_scale`)."""
    return apply_similarity(source, similarity_transform(target, source))
