"""Layout fill: the part of a target view no source saw, drawn as the room's floor, walls and ceiling.

A pseudo-view turned away from every real view is mostly holes, and what a camera sees
there is mostly room: floor, walls and ceiling (93% of the hole pixels of the pseudo-views
of `bench` seed 0, by the workspace's true renders). Cameras are level and the floor is ``z = 0`` (:mod:`ssga_core.geometry`),
so where a hole's ray meets the floor, the ceiling or a wall follows from three
estimates made on the sources' own points:

* the **ceiling height**: the highest plane the sources saw above the camera;
* the **wall distance** around the target camera, per bearing: the median horizontal
  distance of the points in a band just below the ceiling (the top of the walls, above
  doors and furniture), interpolated across bearings no source saw;
* the **texture** of each surface, read from the sources: the floor and the ceiling in
  a top-down map of their points inside those walls, the walls in a map of that band
  around the target. A point past what was seen reads its map mirrored back and forth
  across the seen span (so the band tiles the wall up and down, and a plank or brick
  pattern continues rather than smears); a gap inside it reads the nearest seen cell.

Nothing is filled where the sources show no ceiling or no wall band (an outdoor scene,
a camera that never looks up): the holes stay as they were.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ssga_core import Camera, Pose, View
from ssga_synthesizer_depth_warp.holes import _nearest_drawn

_SURFACE_TOLERANCE = 0.04
"""Points within this (metres) of the floor or the ceiling plane are on it."""
_MIN_PLANE_SHARE = 0.005
"""Fewer of the sources' points than this share on the ceiling plane or in the wall band, and no layout is
guessed; as few on the floor or the ceiling inside the room, and that surface is left unfilled."""
_MIN_CEILING_WIDTH = 0.15
"""The points at the ceiling's height must spread this far (metres, standard deviation across their
narrowest direction) to be a ceiling and not the top edge of a wall."""
_BEARING_BINS = 360
"""Bearings (1 degree each) at which the wall distance is estimated."""
_STRIDE = 2
"""Every second source pixel along each axis is enough for the maps (4 cm cells, 256-pixel views)."""


@dataclass(frozen=True)
class Layout:
    """A room seen from one target pose: its ceiling height and the wall distance per bearing."""

    ceiling: float
    wall_distance: np.ndarray
    """``(_BEARING_BINS,)`` float32: horizontal distance (metres) to the wall at each world bearing."""


def _in_wall_band(height: np.ndarray, ceiling: float, wall_band: float) -> np.ndarray:
    """Which of these heights lie in the band ``wall_band`` metres below the ceiling (above doors and
    furniture), the ceiling plane itself left out."""
    return (height > ceiling - wall_band) & (height < ceiling - _SURFACE_TOLERANCE)


def _least_points(total: int) -> float:
    """Fewest points a plane or the band needs, of ``total`` source points (:data:`_MIN_PLANE_SHARE`)."""
    return max(_MIN_PLANE_SHARE * total, 10)


def _source_points(views: Sequence[View], max_depth: float) -> tuple[np.ndarray, np.ndarray]:
    """World points ``(N, 3)`` and their colours ``(N, C)`` of every source pixel (on a stride) with known depth."""
    points, colours = [], []
    for view in views:
        assert view.depth is not None
        depth = view.depth[::_STRIDE, ::_STRIDE]
        uv = view.camera.pixel_grid()[::_STRIDE, ::_STRIDE]
        known = np.isfinite(depth) & (depth > 0) & (depth <= max_depth)
        cam = view.camera.unproject(depth[known], uv[known])
        points.append(view.pose.to_world(cam))
        colours.append(view.rgb[::_STRIDE, ::_STRIDE][known])
    return np.concatenate(points).astype(np.float32), np.concatenate(colours)


def _bearing_bin(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    return (np.floor((np.arctan2(dy, dx) + np.pi) / (2 * np.pi) * _BEARING_BINS).astype(np.int64)) % _BEARING_BINS


def estimate_layout(points: np.ndarray, target: Pose, wall_band: float) -> Layout | None:
    """The room around ``target`` from the sources' world points; None where they show no ceiling or wall band."""
    height = points[:, 2]
    least = _least_points(len(points))
    above = height[height > target.height + 0.3]
    if len(above) < least:
        return None
    ceiling = float(np.percentile(above, 99.5))
    top = points[np.abs(height - ceiling) < _SURFACE_TOLERANCE, :2]
    # A ceiling is an area: the top edge of a wall, all that is high where no ceiling was seen, is a line.
    if len(top) < least or np.sqrt(np.linalg.eigvalsh(np.cov(top.T))[0]) < _MIN_CEILING_WIDTH:
        return None
    band = points[_in_wall_band(height, ceiling, wall_band)]
    if len(band) < least:
        return None
    dx, dy = band[:, 0] - target.x, band[:, 1] - target.y
    bins = _bearing_bin(dx, dy)
    distance = np.hypot(dx, dy)
    # The median per bearing: a lintel and the far room seen through its doorway share bearings.
    order = np.lexsort((distance, bins))
    bins, distance = bins[order], distance[order]
    starts = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
    counts = np.diff(np.r_[starts, len(bins)])
    seen = bins[starts]
    median = distance[starts + counts // 2]
    # Across the bearings no source saw, interpolate around the circle.
    wrapped = np.r_[seen - _BEARING_BINS, seen, seen + _BEARING_BINS]
    values = np.r_[median, median, median]
    walls = np.interp(np.arange(_BEARING_BINS), wrapped, values).astype(np.float32)
    return Layout(ceiling=ceiling, wall_distance=walls)


class _TextureMap:
    """Colours rasterised on a 2D grid, read tiled: a point past the seen cells is mirrored back among them."""

    def __init__(self, coords: np.ndarray, colours: np.ndarray, cell: float) -> None:
        """``coords``: ``(N, 2)``, N > 0, with their ``colours`` ``(N, C)``; ``cell``: the grid's step."""
        self.cell = cell
        # The tile: the span of the seen coordinates, its sparse fringes (a far stray point) left out.
        self.low = np.percentile(coords, 2, axis=0)
        self.high = np.maximum(np.percentile(coords, 98, axis=0), self.low + cell)
        self.shape = tuple(int(n) for n in np.ceil((self.high - self.low) / cell).astype(int) + 1)
        i, j = self._cells(coords)
        inside = (i >= 0) & (i < self.shape[0]) & (j >= 0) & (j < self.shape[1])
        index = (i * self.shape[1] + j)[inside]
        size = self.shape[0] * self.shape[1]
        count = np.bincount(index, minlength=size)
        channels = colours.reshape(len(colours), -1)[inside].astype(np.float64)
        sums = np.stack([np.bincount(index, weights=channels[:, c], minlength=size) for c in range(channels.shape[1])], 1)
        seen = (count > 0).reshape(self.shape)
        self.colour = (sums / np.maximum(count, 1)[:, None]).astype(np.float32)
        # Unseen cells inside the tile (between scan lines, behind furniture) read their nearest seen one;
        # the tile spans the middle 96% of the points, so some are in it.
        self.nearest = _nearest_drawn(seen)[0]

    def _cells(self, coords: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ij = np.floor((coords - self.low) / self.cell).astype(np.int64)
        return ij[:, 0], ij[:, 1]

    def lookup(self, coords: np.ndarray) -> np.ndarray:
        """``(N, C)`` colours at ``(N, 2)`` coordinates."""
        folded = np.stack([_fold(coords[:, a], self.low[a], self.high[a]) for a in (0, 1)], 1)
        i, j = self._cells(folded)
        i, j = np.clip(i, 0, self.shape[0] - 1), np.clip(j, 0, self.shape[1] - 1)
        return self.colour[self.nearest[i * self.shape[1] + j]]


def _fold(z: np.ndarray, low: float, high: float) -> np.ndarray:
    """Coordinates mirrored back and forth into ``[low, high]``: a map read past its seen span tiles it."""
    period = 2 * (high - low)
    m = np.mod(z - low, period)
    return low + np.where(m < high - low, m, period - m)


def layout_fill(
    rgb: np.ndarray,
    depth: np.ndarray,
    holes: np.ndarray,
    camera: Camera,
    target: Pose,
    views: Sequence[View],
    *,
    wall_band: float = 0.45,
    cell: float = 0.04,
    max_depth: float = 50.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Draw the ``holes`` of a target view as the room's floor, walls and ceiling (the module docstring).

    Returns:
        the image and its planar depth (the layout's where filled); the inputs as they
        were where no layout was found.
    """
    if not holes.any():
        return rgb, depth
    points, colours = _source_points(views, max_depth)
    layout = estimate_layout(points, target, wall_band)
    if layout is None:
        return rgb, depth
    v, u = np.nonzero(holes)
    f = camera.focal_px
    cx, cy = camera.principal_point
    ray_cam = np.stack([(u - cx) / f, (v - cy) / f, np.ones(len(u))], 1)
    ray = ray_cam @ target.rotation().T  # world directions, planar depth 1 along the axis
    bearing = _bearing_bin(ray[:, 0], ray[:, 1])
    # Planar depth at which the ray meets the wall, the floor, or the ceiling.
    t = layout.wall_distance[bearing] / np.hypot(ray[:, 0], ray[:, 1])
    with np.errstate(divide="ignore"):
        t_floor = np.where(ray[:, 2] < 0, target.height / -ray[:, 2], np.inf)
        t_ceiling = np.where(ray[:, 2] > 0, (layout.ceiling - target.height) / ray[:, 2], np.inf)
    surface = np.argmin(np.stack([t, t_floor, t_ceiling]), 0)  # 0 wall, 1 floor, 2 ceiling
    t = np.minimum(t, np.minimum(t_floor, t_ceiling))
    hit = target.position + t[:, None] * ray
    out = rgb.copy()
    out_depth = depth.copy()
    filled = np.zeros_like(holes)
    height = points[:, 2]
    # Floor and ceiling: top-down maps over (x, y) of the points inside the room's walls (not the next
    # room's floor, seen through a doorway).
    dx, dy = points[:, 0] - target.x, points[:, 1] - target.y
    in_room = np.hypot(dx, dy) <= layout.wall_distance[_bearing_bin(dx, dy)] + _SURFACE_TOLERANCE
    for index, on_plane in ((1, in_room & (height < _SURFACE_TOLERANCE)), (2, in_room & (height > layout.ceiling - _SURFACE_TOLERANCE))):
        pick = surface == index
        if not pick.any() or np.count_nonzero(on_plane) < _least_points(len(points)):
            continue
        colour = _TextureMap(points[on_plane, :2], colours[on_plane], cell).lookup(hit[pick, :2])
        out[v[pick], u[pick]] = colour.reshape(-1, *rgb.shape[2:]).astype(rgb.dtype)
        filled[v[pick], u[pick]] = True
    # Walls: the band's points mapped to (arc length around the target, height), the band tiled up and down.
    band = _in_wall_band(height, layout.ceiling, wall_band)
    pick = surface == 0
    if pick.any():
        radius = float(np.median(layout.wall_distance))

        def arc(p: np.ndarray) -> np.ndarray:
            return np.stack([np.arctan2(p[:, 1] - target.y, p[:, 0] - target.x) * radius, p[:, 2]], 1)

        colour = _TextureMap(arc(points[band]), colours[band], cell).lookup(arc(hit[pick]))
        out[v[pick], u[pick]] = colour.reshape(-1, *rgb.shape[2:]).astype(rgb.dtype)
        filled[v[pick], u[pick]] = True
    out_depth[filled] = t[filled[v, u]].astype(depth.dtype)
    return out, out_depth
