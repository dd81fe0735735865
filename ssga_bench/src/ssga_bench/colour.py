"""Colour beside local features: the CIELAB histogram of the window each one describes.

A grey local descriptor (dense SIFT) cannot tell a red sofa from a blue wall, and a
dictionary of ``k`` words keeps little of the colour a learned descriptor saw. A bag-of-words
descriptor with ``colour > 0`` (:class:`ssga_bench.bow.BoWDescriptorConfig`) keeps, beside
each local feature, the colour histogram of a square window around it; a node sums its
features' histograms, and two nodes' cosine mixes their words' and their colours'
(:class:`ssga_bench.bow.BoWDescriptor`; docs/experiments.md, "Colour in the parts").
"""

from __future__ import annotations

import cv2
import numpy as np

COLOUR_BINS = 4
"""Bins per CIELAB channel (4 x 4 x 4)."""

COLOUR_DIM = COLOUR_BINS**3
"""Length of a colour histogram: the columns ``colour > 0`` appends to each local feature."""

_AB_RANGE = (96.0, 160.0)
"""OpenCV's 8-bit a and b (128 is grey) that the bins span; rooms' colours lie well inside
0-255, so the full range would leave most of them in the two middle bins."""


def colour_histograms(rgb: np.ndarray, positions: np.ndarray, side: int) -> np.ndarray:
    """``(N, COLOUR_DIM)`` float32: the CIELAB histogram of the ``side x side`` window around
    each position ``(u, v)``, as shares of its pixels (mirrored at the image's border)."""
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
    lightness = np.minimum(lab[..., 0] * COLOUR_BINS / 256.0, COLOUR_BINS - 1).astype(np.intp)
    lo, hi = _AB_RANGE
    ab = np.clip((lab[..., 1:] - lo) * COLOUR_BINS / (hi - lo), 0, COLOUR_BINS - 1).astype(np.intp)
    bins = (lightness * COLOUR_BINS + ab[..., 0]) * COLOUR_BINS + ab[..., 1]
    h, w = bins.shape
    # Only the windows' own pixels are counted (144 windows read a fraction of the image's
    # histogram maps a box filter per bin would make), one bincount for all of them.
    offsets = np.arange(side) - side // 2
    rows = _mirrored(np.clip(np.rint(positions[:, 1]), 0, h - 1).astype(np.intp)[:, None] + offsets, h)
    cols = _mirrored(np.clip(np.rint(positions[:, 0]), 0, w - 1).astype(np.intp)[:, None] + offsets, w)
    window_bins = bins[rows[:, :, None], cols[:, None, :]].reshape(len(positions), -1)
    keyed = window_bins + COLOUR_DIM * np.arange(len(positions))[:, None]
    counts = np.bincount(keyed.ravel(), minlength=COLOUR_DIM * len(positions)).reshape(len(positions), COLOUR_DIM)
    return (counts / float(side * side)).astype(np.float32)


def _mirrored(index: np.ndarray, n: int) -> np.ndarray:
    """Indices past either end of ``0..n-1`` reflected back in, edge pixel repeated (OpenCV's BORDER_REFLECT)."""
    index = np.where(index < 0, -index - 1, index)
    return np.where(index >= n, 2 * n - index - 1, index)
