"""Ranks and reciprocal ranks of class scores, shared by fusers, descriptors and evaluation."""

from __future__ import annotations

import numpy as np


def ranks(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """1-based rank of each entry along ``axis`` (1 = highest score).

    Ties are broken by position (the lower index ranks first), so ranks along the
    axis are always a permutation of ``1..n``, whatever the scores.
    """
    scores = np.asarray(scores)
    order = np.argsort(-scores, axis=axis, kind="stable")
    out = np.empty_like(order)
    idx = np.arange(1, scores.shape[axis] + 1).reshape([-1 if a == axis % scores.ndim else 1 for a in range(scores.ndim)])
    np.put_along_axis(out, order, np.broadcast_to(idx, order.shape), axis=axis)
    return out


def reciprocal_ranks(scores: np.ndarray, k: float = 0.0, axis: int = -1) -> np.ndarray:
    """``1 / (k + rank)`` along ``axis``: the reciprocal-rank vector of Cormack et al. (2009)."""
    return 1.0 / (k + ranks(scores, axis=axis))
