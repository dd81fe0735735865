"""Dense SIFT: OpenCV SIFT at a fixed keypoint grid, pooled into bag-of-words node features.

The grid is Patch-NetVLAD's (REFERENCE §1): at 256 x 256, its 144 patches of 5 x 5
conv5_3 cells (stride 16) are centred at ``39.5 + 16 j`` px, ``j = 0..11``, so they
span 2.5/16 to 13.5/16 of each side. A dense-SIFT feature sits where a PNV patch
would, so swapping one descriptor for the other changes only what describes the
patches, not which node a patch belongs to. Everything after extraction (dictionary,
reciprocal-rank votes, NBNN, pooling) is :class:`ssga_bench.bow.BoWDescriptor`'s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import cv2
import numpy as np
from pydantic import Field

from ssga_core import Descriptor, LocalFeatures, View, hookimpl
from ssga_bench import BoWDescriptor, BoWDescriptorConfig

_SIFT_SIGMA = 1.6
"""OpenCV SIFT's base blur; a keypoint of size ``s`` was detected at blur ``s / 2``."""
_SIFT_LAYERS = 3
"""OpenCV SIFT's default ``nOctaveLayers``."""
_PNV_MARGIN = 2.5 / 16
"""Outermost PNV patch centre as a fraction of the side (39.5 + 0.5 px of 256)."""


class DenseSiftConfig(BoWDescriptorConfig):
    grid: int = Field(default=12, ge=1, le=64, description="Keypoints per image side: grid x grid features (12 gives PNV's 144).")
    layout: Literal["pnv", "uniform"] = Field(
        default="pnv",
        description="pnv: Patch-NetVLAD's patch centres (2.5/16 to 13.5/16 of each side); uniform: centres of a grid x grid tiling.",
    )
    keypoint_size: float = Field(
        default=24.0,
        gt=0.0,
        le=256.0,
        description="OpenCV keypoint size (px) at 256 x 256, scaled by sqrt(H W) / 256; the descriptor's Gaussian window has sigma 3x this.",
    )
    root_sift: bool = Field(default=False, description="RootSIFT (L1-normalise, then square root); otherwise L2-normalised SIFT.")
    colour: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="Share of a node's similarity given to colour: each keypoint also keeps the colour histogram of its "
        "window (CIELAB, 4 x 4 x 4 bins), a node pools its keypoints' into one, and two nodes' cosine is (1 - colour) times "
        "their words' plus colour times their colours'. 0: grey SIFT words alone.",
    )


def grid_positions(shape: tuple[int, int], grid: int, layout: str = "pnv") -> np.ndarray:
    """``(grid * grid, 2)`` float32 keypoint centres ``(u, v)``, row by row, for an image of ``shape`` (H, W)."""
    h, w = shape
    if grid == 1:
        frac = np.array([0.5])
    elif layout == "pnv":
        frac = np.linspace(_PNV_MARGIN, 1.0 - _PNV_MARGIN, grid)
    else:
        frac = (np.arange(grid) + 0.5) / grid
    uu, vv = np.meshgrid(frac * w - 0.5, frac * h - 0.5)
    return np.stack([uu.ravel(), vv.ravel()], axis=-1).astype(np.float32)


def keypoint_octave(size: float) -> int:
    """OpenCV's packed ``KeyPoint.octave`` (octave | layer << 8) of the pyramid level whose blur matches ``size``.

    With the default octave 0, OpenCV describes every keypoint on the full-resolution
    image, over a window about 6x ``size`` wide: slow (REFERENCE §11: ~28 ms for 144
    keypoints of size 21) and blurred less than SIFT intends. Octaves below 0 would make
    it upsample the image, so they are clamped to 0.
    """
    t = max(math.log2(size / (2.0 * _SIFT_SIGMA)), 0.0)
    octave = int(math.floor(t))
    layer = int(round(_SIFT_LAYERS * (t - octave)))
    if layer == _SIFT_LAYERS:
        octave, layer = octave + 1, 0
    return octave | (layer << 8)


SIFT_DIM = 128

COLOUR_BINS = 4
"""Bins per CIELAB channel of a keypoint's colour histogram (4 x 4 x 4 = 64)."""

_AB_RANGE = (96.0, 160.0)
"""OpenCV's 8-bit a and b (128 is grey) that the bins span; rooms' colours lie well inside
0-255, so the full range would leave most of them in the two middle bins."""


def colour_histograms(rgb: np.ndarray, positions: np.ndarray, side: int) -> np.ndarray:
    """``(N, 64)`` float32: the CIELAB histogram of the ``side x side`` window around each
    position, as shares of its pixels (mirrored at the image's border)."""
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
    nbins = COLOUR_BINS**3
    keyed = window_bins + nbins * np.arange(len(positions))[:, None]
    counts = np.bincount(keyed.ravel(), minlength=nbins * len(positions)).reshape(len(positions), nbins)
    return (counts / float(side * side)).astype(np.float32)


def _mirrored(index: np.ndarray, n: int) -> np.ndarray:
    """Indices past either end of ``0..n-1`` reflected back in, edge pixel repeated (OpenCV's BORDER_REFLECT)."""
    index = np.where(index < 0, -index - 1, index)
    return np.where(index >= n, 2 * n - index - 1, index)


def root_sift(descriptors: np.ndarray) -> np.ndarray:
    """RootSIFT (Arandjelović and Zisserman, 2012): Euclidean distance between results is the Hellinger distance."""
    l1 = np.abs(descriptors).sum(axis=1, keepdims=True)
    return np.sqrt(np.divide(descriptors, l1, out=np.zeros_like(descriptors), where=l1 > 0))


class DenseSift(BoWDescriptor):
    """SIFT descriptors (upright, grey) at ``grid x grid`` fixed keypoints; node features are BoW histograms."""

    name = "dense-sift"
    abbrev = "SIFT"
    Config = DenseSiftConfig

    def _extract(self, view: View) -> LocalFeatures:
        cfg = self.config
        h, w = view.camera.shape
        positions = grid_positions((h, w), cfg.grid, cfg.layout)
        size = cfg.keypoint_size * math.sqrt(h * w) / 256.0
        octave = keypoint_octave(size)
        keypoints = [cv2.KeyPoint(float(u), float(v), size, 0.0, 0.0, octave) for u, v in positions]
        grey = cv2.cvtColor(view.rgb, cv2.COLOR_RGB2GRAY)
        # A new SIFT object per call: cheap, and the descriptor stays picklable for worker processes.
        keypoints, descriptors = cv2.SIFT_create().compute(grey, keypoints)
        descriptors = np.asarray(descriptors, dtype=np.float32).reshape(len(keypoints), 128)
        positions = np.array([kp.pt for kp in keypoints], dtype=np.float32).reshape(-1, 2)
        if cfg.root_sift:
            descriptors = root_sift(descriptors)
        else:
            norm = np.linalg.norm(descriptors, axis=1, keepdims=True)
            descriptors = np.divide(descriptors, norm, out=np.zeros_like(descriptors), where=norm > 0)
        if cfg.colour > 0:
            window = max(int(round(size)), 1)
            descriptors = np.concatenate([descriptors, colour_histograms(view.rgb, positions, window)], axis=1)
        return LocalFeatures(positions=positions, descriptors=descriptors)

    @property
    def dim(self) -> int:
        return self.bow.dim + (COLOUR_BINS**3 if self.config.colour > 0 else 0)

    def _words(self, descriptors: np.ndarray) -> np.ndarray:
        return descriptors[:, :SIFT_DIM]

    def _pool(self, features: LocalFeatures, members: Sequence[np.ndarray]) -> np.ndarray:
        words = super()._pool(features, members)
        share = self.config.colour
        if share <= 0:
            return words
        colours = features.descriptors[:, SIFT_DIM:]
        pooled = np.stack([colours[np.asarray(m, dtype=np.intp)].sum(axis=0) for m in members]) if len(members) else np.zeros((0, colours.shape[1]), np.float32)
        norm = np.linalg.norm(pooled, axis=1, keepdims=True)
        pooled = np.divide(pooled, norm, out=np.zeros_like(pooled), where=norm > 0).astype(np.float32)
        # Both halves at unit length, weighed so that a cosine of two nodes mixes the two cosines by `colour`.
        return np.concatenate([math.sqrt(1 - share) * words, math.sqrt(share) * pooled], axis=1)


@hookimpl
def ssga_register_descriptors() -> list[type[Descriptor]]:
    return [DenseSift]
