"""Hole filling of a warped image: the small gaps nothing was drawn into."""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from ssga_core import InputError

HoleFill = Literal["none", "inpaint", "nearest"]
HOLE_FILLS: tuple[str, ...] = ("none", "inpaint", "nearest")
"""The hole-filling methods :func:`fill_holes` knows."""


def _nearest_drawn(drawn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(H W,)`` each pixel's nearest ``drawn`` pixel (a flat index; itself if drawn), and the distance to it."""
    # The distance transform's labels number the zero (drawn) pixels in raster order.
    distance, labels = cv2.distanceTransformWithLabels(
        (~drawn).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5, labelType=cv2.DIST_LABEL_PIXEL
    )
    labels = labels.ravel()
    labels -= 1
    return np.take(np.flatnonzero(drawn), labels), distance.ravel()


def small_holes(covered: np.ndarray, max_hole: int) -> np.ndarray:
    """``(H, W)`` bool: the uncovered pixels in gaps narrower than ``max_hole`` pixels.

    A morphological closing of the coverage with a ``max_hole x max_hole`` square:
    cracks and pinholes close, while large empty areas (disocclusions, the part of the
    target the source never saw) do not.
    """
    if max_hole <= 1:
        return np.zeros_like(covered, dtype=bool)
    kernel = np.ones((max_hole, max_hole), np.uint8)
    closed = cv2.morphologyEx(covered.astype(np.uint8), cv2.MORPH_CLOSE, kernel)
    return (closed > 0) & ~covered


def fill_holes(image: np.ndarray, covered: np.ndarray, method: HoleFill, max_hole: int = 8) -> np.ndarray:
    """Fill the small holes of a warped image.

    Args:
        image: ``(H, W)`` or ``(H, W, C)`` image; ``"inpaint"`` needs uint8 with 1 or 3 channels.
        covered: ``(H, W)`` bool, the pixels that hold a warped value.
        method: ``"none"`` (return the image as is); ``"inpaint"`` (OpenCV's Telea
            inpainting, radius 3); ``"nearest"`` (the colour of the nearest covered pixel).
        max_hole: only holes narrower than this many pixels are filled (see
            :func:`small_holes`).

    Returns:
        a new image (the input itself for ``"none"`` or when nothing is to fill).
    """
    return _fill(image, covered, method, max_hole, None)


def _fill(image: np.ndarray, covered: np.ndarray, method: HoleFill, max_hole: int, nearest: np.ndarray | None) -> np.ndarray:
    """:func:`fill_holes`, with the nearest covered pixel of every pixel if known already."""
    if method not in HOLE_FILLS:
        raise InputError(f"fill_holes: unknown method {method!r}; known: {', '.join(HOLE_FILLS)}")
    if method == "none":
        return image
    holes = small_holes(covered, max_hole)
    if not holes.any() or not covered.any():
        return image
    if method == "inpaint":
        if image.dtype != np.uint8 or (image.ndim == 3 and image.shape[2] not in (1, 3)):
            raise InputError(f"fill_holes: inpaint needs a uint8 image with 1 or 3 channels, got {image.dtype} {image.shape}")
        # Telea only looks `radius` pixels around each hole pixel; crop to the holes' box.
        v, u = np.nonzero(holes)
        pad = 4
        r0, r1 = max(v.min() - pad, 0), v.max() + pad + 1
        c0, c1 = max(u.min() - pad, 0), u.max() + pad + 1
        out = image.copy()
        out[r0:r1, c0:c1] = np.asarray(
            cv2.inpaint(np.ascontiguousarray(image[r0:r1, c0:c1]), holes[r0:r1, c0:c1].astype(np.uint8), 3, cv2.INPAINT_TELEA)
        ).reshape(out[r0:r1, c0:c1].shape)
        return out
    if nearest is None:
        nearest = _nearest_drawn(covered)[0]
    hole_index = np.flatnonzero(holes)
    out = image.copy()
    flat = out.reshape(covered.size, -1)
    flat[hole_index] = np.take(flat, np.take(nearest, hole_index), axis=0)
    return out
