"""Adaptive footprints: the target pixels a point's source pixel spreads over.

Footprints (``footprint="adaptive"``). A point also covers the target pixels whose
centres map back, through ``J^-1``, into its source pixel (plus a margin), so a surface
the target sees magnified stays closed however close it comes, and hides what is behind
it. Rather than scatter every point into its footprint, the empty target pixels and the
drawn ones farther than a neighbour (a crack in a nearer surface, showing what is
behind) ask the nearest point drawn on its own pixel, which one distance transform
finds for all; where the pixel is not in that point's footprint, steps across the
source grid towards where it maps back find the one it is in. A footprint pixel is taken
only if nearer than what is drawn there by ``depth_tolerance``. Nothing spans a depth
edge: a point without a frame covers its own pixel only, so foreground and background
never smear into "rubber sheets".
"""

from __future__ import annotations

import cv2
import numpy as np

from ssga_synthesizer_depth_warp.cloud import _Cloud, _map_back
from ssga_synthesizer_depth_warp.frames import _to_reads
from ssga_synthesizer_depth_warp.holes import _nearest_drawn
from ssga_synthesizer_depth_warp.resample import _Reads
from ssga_synthesizer_depth_warp.scratch import _SCRATCH, _pixel_grid

_STEPS = 2
"""Steps across the source grid (one pixel each) a footprint query may take."""
_FAR = 1e30
"""A depth farther than any surface (and still finite when raised by the tolerance)."""


def _spread(
    cloud: _Cloud, winner: np.ndarray, covered: np.ndarray, front: np.ndarray, max_footprint: int, depth_tolerance: float
) -> tuple[np.ndarray | None, _Reads | None]:
    """Give the points their footprints (the module docstring); updates the arguments in place.

    Returns:
        for every target pixel, the flat index of the nearest pixel drawn on its own
        point (the hole filling reuses it), and where the footprint pixels read; None
        and None when nothing is drawn.
    """
    assert cloud.frames is not None
    frames = cloud.frames
    oh, ow = covered.shape
    # Empty pixels as farther than anything (a mask multiplies faster than it selects).
    depth = np.multiply(~covered, np.float32(_FAR), out=_SCRATCH.get("spread_depth", (oh, ow), np.float32))
    depth += front[: oh * ow].reshape(oh, ow)
    nearest_depth = cv2.erode(depth, np.ones((3, 3), np.uint8))
    nearest_depth *= np.float32(1.0 + depth_tolerance)
    drawn = depth <= nearest_depth  # not behind a neighbour...
    drawn &= covered  # ...and drawn
    if not drawn.any():
        return None, None
    nearest, distance = _nearest_drawn(drawn)
    asking = np.flatnonzero(~drawn)
    asking = asking[np.take(distance, asking) <= np.float32(max_footprint / 2)]
    point = np.take(winner, np.take(nearest, asking))
    col, row = _pixel_grid(oh, ow)
    col, row = np.take(col, asking), np.take(row, asking)
    joins, back_x, back_y = _in_footprint(cloud, point, col, row)
    # Steps across the source grid, towards where the pixel maps back, find the point
    # whose footprint it is where the nearest one's is not (Voronoi cells and footprints
    # differ where a surface is seen sheared), if a few steps can get there.
    with np.errstate(invalid="ignore"):
        reachable = np.maximum(np.abs(back_x), np.abs(back_y)) <= 1 + _STEPS
    reachable &= ~joins
    retry = np.flatnonzero(reachable)
    for _ in range(_STEPS):
        if not len(retry):
            break
        step_x, step_y = np.rint(back_x[retry]), np.rint(back_y[retry])
        np.clip(step_x, -1, 1, out=step_x)
        np.clip(step_y, -1, 1, out=step_y)
        step_y *= cloud.width
        step_y += step_x
        moved = point[retry] + step_y.astype(point.dtype)
        np.clip(moved, 0, cloud.size, out=moved)  # off the atlas: the sentinel, which has no frame
        point[retry] = moved
        found, back_x[retry], back_y[retry] = _in_footprint(cloud, moved, col[retry], row[retry])
        joins[retry] = found
        retry = retry[~found & (np.take(frames.reach, moved) > 0)]
    point_depth = _surface_depth(cloud, point, back_x, back_y)
    joins &= point_depth * np.float32(1.0 + depth_tolerance) < np.take(depth, asking)
    pixels, point, back_x, back_y = asking[joins], point[joins], back_x[joins], back_y[joins]
    winner[pixels] = point
    front[pixels] = point_depth[joins]
    covered.ravel()[pixels] = True
    atlas_col, atlas_row = _pixel_grid(cloud.rows[-1], cloud.width)
    _to_reads(back_x, back_y, np.take(frames.interior, point), np.take(atlas_col, point), np.take(atlas_row, point))
    return nearest, _Reads(pixels, back_x, back_y)


def _surface_depth(cloud: _Cloud, point: np.ndarray, back_x: np.ndarray, back_y: np.ndarray) -> np.ndarray:
    """The target depth of ``point``'s surface where a footprint pixel maps back to, ``(back_x, back_y)`` source
    pixels from it: its inverse depth extended to first order by the steps to its right and lower neighbours.

    A footprint pixel takes this depth rather than the point's own, so that on a surface seen
    steeply (its depth changing by more than ``depth_tolerance`` from pixel to pixel) a
    neighbour's footprint is not "nearer" than the pixel's own point, and neither displaces
    it nor hides it from ``visible``. Only framed points reach here, and a frame exists only
    where both neighbours are on the point's surface.
    """
    z = np.take(cloud.z, point)
    right = np.take(cloud.z, np.minimum(point + 1, cloud.size))
    down = np.take(cloud.z, np.minimum(point + cloud.width, cloud.size))
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / z
        surface = inverse + back_x * (1.0 / right - inverse) + back_y * (1.0 / down - inverse)
        # Where extending fails (a neighbour unknown, or a grazing surface extended past its
        # horizon), keep the point's own depth.
        return np.where(np.isfinite(surface) & (surface > 0), 1.0 / surface, z).astype(np.float32)


def _in_footprint(
    cloud: _Cloud, point: np.ndarray, col: np.ndarray, row: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whether target pixels ``(col, row)`` are in ``point``'s footprint (within its :attr:`_Frames.reach`),
    and where they map back (:func:`_map_back`)."""
    assert cloud.frames is not None
    back_x, back_y = _map_back(cloud, point, col, row)
    distance = np.abs(back_x)
    np.maximum(distance, np.abs(back_y), out=distance)
    with np.errstate(invalid="ignore"):  # NaN: no frame, and no footprint
        inside = distance <= np.take(cloud.frames.reach, point)
    return inside, back_x, back_y
