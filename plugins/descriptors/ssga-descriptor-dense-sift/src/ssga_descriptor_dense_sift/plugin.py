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
        return LocalFeatures(positions=positions, descriptors=descriptors)

    def colour_window(self, view: View) -> int:
        """A keypoint's size: the colours of the square its SIFT window is centred on (``colour > 0``)."""
        h, w = view.camera.shape
        return max(int(round(self.config.keypoint_size * math.sqrt(h * w) / 256.0)), 1)


@hookimpl
def ssga_register_descriptors() -> list[type[Descriptor]]:
    return [DenseSift]
