"""The colour of each drawn target pixel, read from the sources.

Resampling (``resample="bilinear"``). A drawn pixel reads its colour bilinearly where its
centre maps back to in the source, through its point's ``J^-1``: exact to first order,
where the point's own colour is up to 0.7 px off. Only points whose four neighbours are
on their surface read between pixels (within one of their own), so no read mixes two
surfaces. Small holes filled ``"nearest"`` read the same way, through the point drawn at
the nearest drawn pixel: a crack in a surface gets that surface's colour at the crack.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from ssga_synthesizer_depth_warp.cloud import _Cloud, _map_back
from ssga_synthesizer_depth_warp.frames import _to_reads
from ssga_synthesizer_depth_warp.holes import _nearest_drawn, small_holes
from ssga_synthesizer_depth_warp.scratch import _SCRATCH, _arange, _pixel_grid

_REMAP_LIMIT = 32767
"""OpenCV's remap reads positions as 16-bit integers: stacked sources must stay below this many rows and columns."""


class _Reads(NamedTuple):
    """Target pixels that read elsewhere than their point's own pixel would (footprints,
    filled holes), and where in the atlas."""

    pixels: np.ndarray
    read_x: np.ndarray
    read_y: np.ndarray


def _hole_reads(
    cloud: _Cloud, winner: np.ndarray, covered: np.ndarray, max_hole: int, nearest: np.ndarray | None
) -> _Reads | None:
    """Where the small holes (:func:`small_holes`) read: through the frame of the point drawn at the nearest drawn pixel."""
    assert cloud.frames is not None
    pixels = np.flatnonzero(small_holes(covered, max_hole))
    if not len(pixels) or not covered.any():
        return None
    if nearest is None:
        nearest = _nearest_drawn(covered)[0]
    point = np.take(winner, np.take(nearest, pixels))
    col, row = _pixel_grid(*covered.shape)
    read_x, read_y = _map_back(cloud, point, np.take(col, pixels), np.take(row, pixels))
    atlas_col, atlas_row = _pixel_grid(cloud.rows[-1], cloud.width)
    _to_reads(read_x, read_y, np.take(cloud.frames.interior, point), np.take(atlas_col, point), np.take(atlas_row, point))
    return _Reads(pixels, read_x, read_y)


def _remappable(images: list[np.ndarray]) -> bool:
    """Whether OpenCV's remap takes these images, stacked."""
    first = images[0]
    return (
        first.dtype in (np.uint8, np.uint16, np.int16, np.float32, np.float64)
        and (first.ndim == 2 or first.shape[2] <= 4)
        and sum(image.shape[0] for image in images) < _REMAP_LIMIT
        and max(image.shape[1] for image in images) < _REMAP_LIMIT
    )


def _resample_nearest(cloud: _Cloud, images: list[np.ndarray], winner: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Each target pixel takes its point's colour (the sentinel's: zero)."""
    atlas = cloud.atlas(images)
    channels = atlas.shape[2:]
    n = cloud.size
    pixels = _SCRATCH.get("pixels", (n + 1, *channels), atlas.dtype)
    pixels[:n] = atlas.reshape(n, *channels)
    pixels[n] = 0
    # mode="clip" skips the bounds checks and the buffering of `out` (indices are valid).
    return np.take(pixels, winner, axis=0, mode="clip").reshape(*shape, *channels)


def _resample_bilinear(
    cloud: _Cloud,
    images: list[np.ndarray],
    winner: np.ndarray,
    shape: tuple[int, int],
    reads: list[_Reads | None],
    own: np.ndarray | None,
) -> np.ndarray:
    """Each target pixel's colour, read bilinearly where it maps back to in its point's source.

    One ``cv2.remap`` of the atlas. A pixel drawn on its point's own pixel reads where
    the point's frame says (:class:`_Frames`), the pixels of ``reads`` where they say;
    with ``own`` (each point's own pixel: squares were drawn), a pixel drawn by another's
    square maps back on its own. An empty pixel reads far off the atlas, and so zero.
    """
    assert cloud.frames is not None
    frames = cloud.frames
    oh, ow = shape
    map_x = np.take(frames.read_x, winner, out=_SCRATCH.get("map_x", oh * ow, np.float32), mode="clip")
    map_y = np.take(frames.read_y, winner, out=_SCRATCH.get("map_y", oh * ow, np.float32), mode="clip")
    if own is not None:
        elsewhere = np.take(own, winner, mode="clip") != _arange(oh * ow)
        elsewhere &= winner < cloud.size
        pixels = np.flatnonzero(elsewhere)
        point = winner[pixels]
        col, row = _pixel_grid(oh, ow)
        read_x, read_y = _map_back(cloud, point, col[pixels], row[pixels])
        atlas_col, atlas_row = _pixel_grid(cloud.rows[-1], cloud.width)
        _to_reads(read_x, read_y, np.take(frames.interior, point), np.take(atlas_col, point), np.take(atlas_row, point))
        map_x[pixels], map_y[pixels] = read_x, read_y
    for given in reads:
        if given is not None:
            map_x[given.pixels], map_y[given.pixels] = given.read_x, given.read_y
    atlas = cloud.atlas(images)
    out = cv2.remap(atlas, map_x.reshape(oh, ow), map_y.reshape(oh, ow), cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return out.reshape(oh, ow, *atlas.shape[2:])
