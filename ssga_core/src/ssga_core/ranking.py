"""Ranks and reciprocal ranks of class scores, shared by fusers, descriptors and evaluation."""

from __future__ import annotations

from typing import Literal

import numpy as np

Ties = Literal["ordinal", "average"]
"""How equal scores rank: ``"ordinal"`` breaks ties by position (the lower index first),
``"average"`` lets the tied entries share their block of ranks equally."""


def _descending(scores: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """``scores`` with ``axis`` moved last, and their descending order along it (stable: equal scores keep their positions)."""
    scores = np.moveaxis(np.asarray(scores), axis, -1)
    return scores, np.argsort(-scores, axis=-1, kind="stable")


def _sorted_blocks(scores: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The descending order along ``axis`` (moved last), and for each sorted position the
    0-based first and last position of its block of equal scores."""
    scores, order = _descending(scores, axis)
    ordered = np.take_along_axis(scores, order, axis=-1)
    n = ordered.shape[-1]
    position = np.broadcast_to(np.arange(n), ordered.shape)
    differs = ordered[..., 1:] != ordered[..., :-1]
    opens = np.concatenate([np.ones_like(differs[..., :1]), differs], axis=-1)
    closes = np.concatenate([differs, np.ones_like(differs[..., :1])], axis=-1)
    first = np.maximum.accumulate(np.where(opens, position, 0), axis=-1)
    last = np.flip(np.minimum.accumulate(np.flip(np.where(closes, position, n - 1), axis=-1), axis=-1), axis=-1)
    return order, first, last


def _check(ties: str) -> None:
    if ties not in ("ordinal", "average"):
        raise ValueError(f"ties must be 'ordinal' or 'average', got {ties!r}")


def _unsorted(values: np.ndarray, order: np.ndarray, axis: int) -> np.ndarray:
    """``values`` given in sorted order (axis last), put back at the entries they belong to, axis restored."""
    out = np.empty(values.shape, dtype=values.dtype)
    np.put_along_axis(out, order, values, axis=-1)
    return np.moveaxis(out, -1, axis)


def ranks(scores: np.ndarray, axis: int = -1, ties: Ties = "ordinal") -> np.ndarray:
    """1-based rank of each entry along ``axis`` (1 = highest score).

    ``ties="ordinal"``: ties are broken by position (the lower index ranks first), so ranks
    along the axis are always a permutation of ``1..n``, whatever the scores.
    ``ties="average"``: tied entries take the mean of the ranks they span (floats).
    """
    _check(ties)
    if ties == "ordinal":
        _, order = _descending(scores, axis)
        by_position = np.broadcast_to(np.arange(1, order.shape[-1] + 1), order.shape)
        return _unsorted(np.ascontiguousarray(by_position), order, axis)
    order, first, last = _sorted_blocks(scores, axis)
    return _unsorted((first + last) / 2.0 + 1.0, order, axis)


def reciprocal_ranks(scores: np.ndarray, k: float = 0.0, axis: int = -1, ties: Ties = "ordinal") -> np.ndarray:
    """``1 / (k + rank)`` along ``axis``: the reciprocal-rank vector of Cormack et al. (2009).

    ``ties="average"``: tied entries share the *mean of the reciprocal ranks* they span, so
    the block's total vote is kept and no entry in it is preferred. A fuser needs this: a
    variant that cannot tell some classes apart (one without synthesis scores every heading
    of a cell alike) must not vote for them in class-index order.
    """
    _check(ties)
    if ties == "ordinal":
        return 1.0 / (k + ranks(scores, axis=axis))
    order, first, last = _sorted_blocks(scores, axis)
    n = order.shape[-1]
    # Prefix sums of 1 / (k + rank) over ranks 1..n: a block's sum is a difference of two.
    prefix = np.concatenate([[0.0], np.cumsum(1.0 / (k + np.arange(1, n + 1)))])
    shared = (prefix[last + 1] - prefix[first]) / (last - first + 1)
    return _unsorted(shared, order, axis)
