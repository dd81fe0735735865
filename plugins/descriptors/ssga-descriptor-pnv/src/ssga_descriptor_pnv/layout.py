"""Patch-NetVLAD's shape without torch: the encoder's widths, the conv5_3 grid, the patch centres.

Config validation and ``ssga variants --list`` / ``ssga plugins`` need these, and they
must not import torch (seconds); :mod:`.model` builds the network from the same values.
"""

from __future__ import annotations

import numpy as np

VGG16_WIDTHS: tuple[int, int, int, int, int] = (64, 128, 256, 512, 512)
"""Output channels of VGG16's five conv blocks (torchvision's ``vgg16``)."""

LIGHT_WIDTHS: tuple[int, int, int, int, int] = (16, 32, 64, 128, 128)
"""The light network: VGG16 with every block 4x narrower (about 1/16 of the compute)."""

STRIDE = 16
"""Pixels between neighbouring conv5_3 cells (four 2 x 2 max-pools)."""
RECEPTIVE_FIELD = 196
"""Side of a conv5_3 cell's receptive field, pixels (PNV's ``calc_receptive_boxes``)."""
PADDING = 90
"""How far the first cell's receptive field starts before pixel 0 (ditto)."""


def patch_grid(feature_shape: tuple[int, int], patch_size: int = 5, stride: int = 1) -> np.ndarray:
    """``(P, 2)`` float32 ``(u, v)`` pixel centres of the patches of a ``(H, W)`` conv5_3 map, row by row.

    A conv5_3 cell ``c`` sees pixels ``STRIDE * c - PADDING`` to that ``+ RECEPTIVE_FIELD - 1``,
    centred at ``16 c + 7.5``; a patch's centre is the middle of its first and last cells'
    (PNV's ``calc_keypoint_centers_from_patches``, kept as floats). Pixel ``i`` covers
    ``[i - 0.5, i + 0.5]``. At 256 x 256: 16 x 16 cells, 12 x 12 patches of 5, centred at
    ``39.5 + 16 j`` px.
    """
    rows = _centres(feature_shape[0], patch_size, stride)
    cols = _centres(feature_shape[1], patch_size, stride)
    uu, vv = np.meshgrid(cols, rows)
    return np.stack([uu.ravel(), vv.ravel()], axis=-1).astype(np.float32)


def _centres(cells: int, patch_size: int, stride: int) -> np.ndarray:
    first = np.arange(0, cells - patch_size + 1, stride, dtype=np.float64)
    half_rf = (RECEPTIVE_FIELD - 1) / 2.0
    start = STRIDE * first - PADDING + half_rf
    end = STRIDE * (first + patch_size - 1) - PADDING + half_rf
    return (start + end) / 2.0
