"""numpy or torch: the few array functions whose names or arguments differ between the two.

The hand model's forward pass, the rotations and the projection are written once over these, so the same
formula runs on numpy arrays (the API process, which must not import torch) and on torch tensors (the
workers, differentiable). torch is never imported here: a tensor's own module is looked up when one is
passed, so numpy callers stay torch-free.
"""

from __future__ import annotations

import sys
from types import ModuleType
from typing import Any

import numpy as np

Array = Any  # np.ndarray or torch.Tensor; the annotation names both without importing torch


def namespace(x: Array) -> ModuleType:
    """`torch` for a tensor, else `numpy`: the module whose functions (stack, concat, where, sin, einsum,
    broadcast_to ...) apply to `x` with numpy's argument names (torch accepts axis= and keepdims=)."""
    if type(x).__module__.startswith("torch"):
        return sys.modules["torch"]
    return np


def copy(x: Array) -> Array:
    """A copy that may be written in place without touching `x` (torch: `clone`, kept in the graph)."""
    return np.array(x, copy=True) if namespace(x) is np else x.clone()


def eye_like(n: int, like: Array) -> Array:
    """(n, n) identity of `like`'s dtype (and device)."""
    xp = namespace(like)
    if xp is np:
        return np.eye(n, dtype=like.dtype)
    return xp.eye(n, dtype=like.dtype, device=like.device)


def constant_like(values: Any, like: Array) -> Array:
    """`values` as an array of `like`'s kind, dtype (and device)."""
    xp = namespace(like)
    if xp is np:
        return np.asarray(values, dtype=like.dtype)
    return xp.as_tensor(values, dtype=like.dtype, device=like.device)


def clip_min(x: Array, low: float) -> Array:
    """max(x, low) elementwise (torch: `clamp`, whose gradient is 0 below `low`)."""
    return np.maximum(x, low) if namespace(x) is np else x.clamp(min=low)
