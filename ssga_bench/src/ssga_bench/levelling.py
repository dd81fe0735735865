"""Levelling a scene whose up is not ``+z``: what the mesh and folder workspace sources share.

A scan or a sequence comes in its reconstruction's frame. Each source finds the up
direction its own way (a mesh from its surfaces' normals, a sequence from its cameras and
depth); both then turn the scene so that up is ``+z`` (:func:`rotation_to_z`) and put the
floor at ``z = 0``: the lowest well-populated level of upward-facing surfaces
(:func:`lowest_level`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

LEVEL_BIN = 0.02
"""Heights are binned at 2 cm to find the levels that surfaces stand at."""


def rotation_to_z(up: np.ndarray) -> np.ndarray:
    """The ``3 x 3`` rotation by the smallest angle that takes the unit vector ``up`` to ``+z`` (Rodrigues)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    sin, cos = float(np.linalg.norm(axis)), float(np.dot(up, z))
    if sin < 1e-12:
        # Already up, or upside down: a half turn about x (any horizontal axis would do).
        return np.eye(3) if cos > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / sin
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + sin * kx + (1.0 - cos) * kx @ kx


def weighted_quantiles(values: np.ndarray, weights: np.ndarray, qs: Sequence[float]) -> list[float]:
    """The ``qs`` quantiles of ``values``, each counting as much as its weight."""
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    at = np.minimum(np.searchsorted(cumulative, np.asarray(qs) * cumulative[-1]), len(values) - 1)
    return [float(v) for v in values[order][at]]


def lowest_level(z: np.ndarray, weights: np.ndarray, share: float) -> float:
    """The floor's height among upward-facing surfaces at heights ``z`` with areas ``weights``:
    the lowest level holding at least ``share`` of the fullest level's area (levels summed over
    5 bins, 10 cm, so that a scanned floor's noise does not split it), at the area-weighted
    median height of the surfaces within 2 bins of it."""
    bins = np.floor((z - z.min()) / LEVEL_BIN).astype(np.int64)
    per_level = np.convolve(np.bincount(bins, weights=weights), np.ones(5), mode="same")
    lowest = int(np.flatnonzero(per_level >= share * per_level.max())[0])
    on_floor = np.abs(bins - lowest) <= 2
    return weighted_quantiles(z[on_floor], weights[on_floor], (0.5,))[0]
