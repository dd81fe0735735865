"""What the protocol makes of a view on one floor plan: the cell it belongs to, its heading
class, what it sees; and the canonical viewpoint of each class, which decides whether a
cell is eligible (the definitions: :mod:`ssga_bench.protocol`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely

from ssga_core.geometry import Camera, Pose
from ssga_bench.protocol_config import ProtocolConfig
from ssga_bench.protocol_plan import Grid
from ssga_bench.visibility import cast_rays, occluder_segments, sees, visibility_polygon
from ssga_bench.workspace import FloorPlan

VIEWPOINT_STEPS = (1.0, 0.75, 0.5, 0.25, 0.125)
"""Shares of ``viewpoint_distance`` a canonical viewpoint may stand behind its cell's
centroid, farthest first. The first three are the distances the protocol has always
tried (it also tried 1.25 and 1.5 times, which no cell drawn in the demo's or the
bench's homes used), so the viewpoints of a plan they fit stay where they were. The
quarter and the eighth let a 1 m cell whose centroid is 0.4 m from a wall (free floor
ends 0.25 m from it) look away from the wall: in furnished rooms of 12 m^2 they took
the 1 m cells seen from all 12 headings from 2.4 to 5.9 on average
(``scripts/protocol_cells.py``)."""


class ProtocolGeometry:
    """The grid, visibility cones, cell assignment and canonical viewpoints of one floor plan
    and camera: what :class:`~ssga_bench.protocol.Protocol` draws its plan with."""

    def __init__(self, floor_plan: FloorPlan, camera: Camera, config: ProtocolConfig | None = None, grid: Grid | None = None) -> None:
        """``grid``: the cells' grid, where the plan is not the one it was drawn on (default: the grid covering it)."""
        self.camera = camera
        self.config = config or ProtocolConfig()
        self.grid = grid or Grid.covering(floor_plan.bounds, self.config.cell_size)
        self.centroids = self.grid.centroids()
        self.floor_plan = floor_plan
        self.segments = occluder_segments(floor_plan.occluders)
        self._free = floor_plan.free
        shapely.prepare(self._free)
        # Captured poses may stand a little closer to walls than the plan's free floor allows.
        self._free_tolerant = floor_plan.free.buffer(0.1)
        shapely.prepare(self._free_tolerant)

    # --- geometry -------------------------------------------------------------
    def orientation_of(self, yaw: np.ndarray | float) -> np.ndarray:
        """Heading class of each yaw: bins centred on multiples of ``360 / orientations``."""
        step = 2 * math.pi / self.config.orientations
        return np.mod(np.rint(np.asarray(yaw) / step), self.config.orientations).astype(int)

    def heading(self, orientation: int) -> float:
        return orientation * 2 * math.pi / self.config.orientations

    def rays(self, xy: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        c = self.config
        return cast_rays(xy, yaws, self.camera.hfov_deg, self.segments, c.max_range, c.rays)

    def assign(self, xy: np.ndarray, yaws: np.ndarray, distances: np.ndarray | None = None) -> np.ndarray:
        """``(B,)`` grid cell of each view (``-1`` for none): the nearest centroid in its cone."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        yaws = np.asarray(yaws, dtype=np.float64).reshape(-1)
        if distances is None:
            distances = self.rays(xy, yaws)
        visible = sees(xy, yaws, distances, self.camera.hfov_deg, self.centroids)  # (B, C)
        dist = np.linalg.norm(self.centroids[None] - xy[:, None], axis=-1)
        dist = np.where(visible, dist, np.inf)
        cell = dist.argmin(axis=1)
        return np.where(np.isfinite(dist.min(axis=1)), cell, -1)

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy).reshape(-1, 2)
        return shapely.contains_xy(self._free, xy[:, 0], xy[:, 1])

    def polygon(self, pose: Pose, distances: np.ndarray | None = None) -> shapely.Polygon:
        if distances is None:
            distances = self.rays(np.array([[pose.x, pose.y]]), np.array([pose.yaw]))[0]
        return visibility_polygon(pose, self.camera.hfov_deg, distances)

    def canonical_viewpoints(self, cell: int, height: float) -> list[tuple[Pose, float] | None]:
        """The canonical viewpoint of each heading class of ``cell``, with the share of
        ``viewpoint_distance`` it stands back (:data:`VIEWPOINT_STEPS`); None for a class
        that has none."""
        c = self.config
        yaws = [self.heading(o) for o in range(c.orientations)]
        back = -np.array([[math.cos(yaw), math.sin(yaw)] for yaw in yaws])
        found: list[tuple[Pose, float] | None] = [None] * c.orientations
        for step in VIEWPOINT_STEPS:
            todo = [o for o in range(c.orientations) if found[o] is None]
            if not todo:
                break
            xy = self.centroids[cell] + back[todo] * c.viewpoint_distance * step
            good = self.is_free(xy)
            if good.any():
                good[good] = self.assign(xy[good], np.array(yaws)[todo][good]) == cell
            for o, (x, y), ok in zip(todo, xy, good):
                if ok:
                    found[o] = (Pose(float(x), float(y), yaws[o], height), step)
        return found

    def free_cells(self, rng: np.random.Generator | None = None) -> list[int]:
        """Grid cells whose centroid is free floor, in a random order drawn from ``rng`` (else by index)."""
        order = rng.permutation(len(self.centroids)) if rng is not None else range(len(self.centroids))
        return [int(k) for k in order if self.is_free(self.centroids[k])[0]]

    def eligible_cells(self, candidates: Sequence[int], height: float, limit: int | None = None) -> list[int]:
        """The ``candidates`` whose every heading class has a canonical viewpoint (the first ``limit``)."""
        found = []
        for cell in candidates:
            if all(v is not None for v in self.canonical_viewpoints(cell, height)):
                found.append(cell)
                if len(found) == limit:
                    break
        return found
