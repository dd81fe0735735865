"""A floor plan of what views saw: for a folder of captures that has none drawn by hand, and
for the training plan, which may know only what the robot's real views saw (never the map).

Two kinds of evidence, on a grid of ``resolution`` (10 cm) over the floor plane:

* **Where the cameras went** (always): the robot stood at every capture, so a disc of
  ``robot_radius`` around each is free floor, and so is the path between two captures
  that follow each other in the file less than ``max_step`` apart (a robot's
  trajectory, recorded in order).
* **What the cameras saw** (captures with depth): each depth map is back-projected
  into the world (every ``stride``-th pixel, up to ``max_depth``) with its camera's pose,
  pitched and rolled as it was where a sequence gives 6-DoF poses. Points on the floor
  (``|z| <= floor_tolerance``) mark cells as seen-free floor; points above it and no
  higher than the camera plus ``band`` are obstacles, and no cell within ``clearance``
  of one is free; points within ``band`` of the camera's height (walls, tall furniture)
  are the occluders the visibility cones stop at, as the mesh workspace takes the
  mesh's cross-section at camera height. A cell counts as seen if ``min_hits`` points
  fall in it, so a stray depth pixel marks nothing.

Free floor = (seen floor, small gaps closed, less what is near an obstacle) plus where
the cameras went. What this cannot know: the folder workspace's README.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from ssga_core.errors import InputError
from ssga_core.geometry import Camera, Pose
from ssga_bench.workspace import FloorPlan, grid_polygons


@dataclass(frozen=True)
class DerivedPlan:
    """A floor plan derived from captures, and what it was derived from."""

    plan: FloorPlan
    poses: int
    depth_views: int

    def describe(self) -> str:
        source = f"{self.poses} capture poses" + (f" and {self.depth_views} depth images" if self.depth_views else " (no depth: no occluders)")
        return f"floor plan derived from {source}: {self.plan.free.area:.1f} m^2 of free floor, {self.plan.occluders.area:.1f} m^2 of occluders"


def floor_plan_from_captures(
    poses: Sequence[Pose],
    camera: Camera,
    depths: Iterable[np.ndarray | None],
    *,
    transforms: Sequence[np.ndarray] | None = None,
    resolution: float = 0.1,
    robot_radius: float = 0.3,
    clearance: float = 0.25,
    max_depth: float = 6.0,
    max_step: float = 1.0,
    floor_tolerance: float = 0.1,
    band: float = 0.3,
    stride: int = 4,
    min_hits: int = 2,
    source: str = "captures",
) -> DerivedPlan:
    """Derive where a camera may stand and what blocks sight from capture poses and depth (see the module docstring).

    Args:
        poses: every capture's pose, in the file's order.
        camera: the captures' camera.
        depths: each capture's planar depth in metres (``0`` or non-finite: unknown), or None.
        transforms: each capture's ``4 x 4`` camera-to-world transform where the camera is
            pitched or rolled (its depth is put back into the world with it); default: the poses'.

    Raises:
        InputError: no capture, or a depth map of another shape than the camera's; naming ``source``.
    """
    if not poses:
        raise InputError(f"{source}: no capture poses to derive a floor plan from")
    evidence = FloorEvidence(
        camera, float(np.median([p.height for p in poses])), max_depth=max_depth, floor_tolerance=floor_tolerance, band=band, stride=stride, source=source
    )
    transforms = transforms if transforms is not None else [p.world_from_camera() for p in poses]
    for k, (pose, transform, depth) in enumerate(zip(poses, transforms, depths, strict=True)):
        evidence.add(k, transform, pose.height, depth)
    return evidence.plan(poses, resolution=resolution, robot_radius=robot_radius, clearance=clearance, max_step=max_step, min_hits=min_hits)


class FloorEvidence:
    """What the depth of the captures saw, gathered one capture at a time (so each depth map
    is read once, when it is checked), then made a plan of with the poses kept."""

    def __init__(
        self,
        camera: Camera,
        camera_height: float,
        *,
        max_depth: float = 6.0,
        floor_tolerance: float = 0.1,
        band: float = 0.3,
        stride: int = 4,
        source: str = "captures",
    ) -> None:
        self.camera, self.camera_height = camera, camera_height
        self.max_depth, self.floor_tolerance, self.band, self.stride, self.source = max_depth, floor_tolerance, band, stride, source
        self.floor_points: list[np.ndarray] = []
        self.obstacle_points: list[np.ndarray] = []
        self.occluder_points: list[np.ndarray] = []
        self.origins: list[np.ndarray] = []
        self.views = 0

    def add(self, k: int, transform: np.ndarray, height: float, depth: np.ndarray | None) -> None:
        """Capture ``k``'s depth (planar, metres, on the camera's grid) seen from ``transform`` (camera to world)."""
        if depth is None:
            return
        camera = self.camera
        if depth.shape != camera.shape:
            raise InputError(f"{self.source}: capture {k}'s depth is {depth.shape[1]}x{depth.shape[0]}, its image {camera.width}x{camera.height}")
        points = _world_points(transform, camera, depth, self.stride, self.max_depth)
        self.views += 1
        z = points[:, 2]
        self.floor_points.append(points[np.abs(z) <= self.floor_tolerance, :2])
        self.obstacle_points.append(points[(z > self.floor_tolerance) & (z <= height + self.band), :2])
        self.occluder_points.append(points[np.abs(z - self.camera_height) <= self.band, :2])
        self.origins.append(transform[:2, 3])

    def plan(
        self,
        poses: Sequence[Pose],
        *,
        resolution: float = 0.1,
        robot_radius: float = 0.3,
        clearance: float = 0.25,
        max_step: float = 1.0,
        min_hits: int = 2,
        free_in_sight: bool = False,
        presumed_free: BaseGeometry | None = None,
    ) -> DerivedPlan:
        """The floor plan of the captures at ``poses`` (in order) and the depth added.

        ``free_in_sight``: the floor between each camera and the first obstacle its depth saw in
        each direction is free too, though the camera saw no floor there (the floor just ahead of
        a level camera is below its field of view). ``presumed_free``: floor taken as free, though no
        camera saw it, less what is near a seen obstacle."""
        if not poses:
            raise InputError(f"{self.source}: no capture poses to derive a floor plan from")
        xy = np.array([[p.x, p.y] for p in poses], dtype=np.float64)
        swept = _swept(xy, robot_radius, max_step)
        if not self.views:
            return DerivedPlan(FloorPlan(free=swept, occluders=shapely.Polygon()), len(poses), 0)
        grid = _Grid.covering(np.concatenate([xy, *self.floor_points, *self.obstacle_points]), resolution, margin=robot_radius + clearance)
        seen_floor = grid.polygons(grid.hits(self.floor_points) >= min_hits)
        # Close the gaps between the sampled pixels' footprints far from the camera (a cell or two).
        seen_floor = seen_floor.buffer(resolution, join_style="mitre").buffer(-resolution, join_style="mitre")
        obstacles = grid.polygons(grid.hits(self.obstacle_points) >= min_hits)
        occluders = grid.polygons(grid.hits(self.occluder_points) >= min_hits).difference(swept)
        if free_in_sight:
            fans = [_sight(o, f, b, self.camera.hfov_deg) for o, f, b in zip(self.origins, self.floor_points, self.obstacle_points)]
            seen_floor = shapely.union(seen_floor, shapely.union_all(fans))
        if presumed_free is not None:
            seen_floor = shapely.union(seen_floor, presumed_free)
        free = shapely.union(seen_floor.difference(obstacles.buffer(clearance)), swept)
        # Staircase outlines simplified to the grid's own precision: fewer edges for every visibility ray to test.
        occluders = occluders.simplify(resolution / 2.0)
        return DerivedPlan(FloorPlan(free=_polygonal(free), occluders=_polygonal(occluders)), len(poses), self.views)


def _swept(xy: np.ndarray, radius: float, max_step: float) -> BaseGeometry:
    """Discs around the capture positions, joined where consecutive captures are less than ``max_step`` apart."""
    parts = list(shapely.points(xy))
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    parts += [shapely.LineString(xy[k : k + 2]) for k in np.flatnonzero((steps > 0) & (steps < max_step))]
    return shapely.union_all(shapely.buffer(parts, radius, quad_segs=4))


def _sight(origin: np.ndarray, floor: np.ndarray, obstacles: np.ndarray, hfov_deg: float, bins: int = 64) -> shapely.Polygon:
    """The floor a camera at ``origin`` saw is clear: in each of ``bins`` directions over its field of
    view, up to the nearest obstacle point, or the farthest floor point where it saw no obstacle."""
    everything = np.concatenate([floor, obstacles]) - origin
    if not len(everything):
        return shapely.Polygon()
    forward = math.atan2(everything[:, 1].mean(), everything[:, 0].mean())
    half = math.radians(hfov_deg) / 2

    def bin_of(xy: np.ndarray) -> np.ndarray:
        turn = np.remainder(np.arctan2(xy[:, 1], xy[:, 0]) - forward + math.pi, 2 * math.pi) - math.pi
        return np.clip(((turn + half) / (2 * half) * bins).astype(np.int64), 0, bins - 1)

    reach = np.zeros(bins)
    np.maximum.at(reach, bin_of(floor - origin), np.linalg.norm(floor - origin, axis=1))
    nearest = np.full(bins, np.inf)
    np.minimum.at(nearest, bin_of(obstacles - origin), np.linalg.norm(obstacles - origin, axis=1))
    reach = np.where(np.isfinite(nearest), nearest, reach)
    edges = forward - half + np.arange(bins + 1) * (2 * half / bins)
    corners = [origin]
    for b in range(bins):
        for angle in (edges[b], edges[b + 1]):
            corners.append(origin + reach[b] * np.array([math.cos(angle), math.sin(angle)]))
    fan = shapely.Polygon(corners).buffer(0)
    return fan if fan.geom_type == "Polygon" else _polygonal(fan)


def _world_points(transform: np.ndarray, camera: Camera, depth: np.ndarray, stride: int, max_depth: float) -> np.ndarray:
    """``(N, 3)`` world points of every ``stride``-th pixel with a depth up to ``max_depth``."""
    uv = camera.pixel_grid()[::stride, ::stride].reshape(-1, 2)
    d = np.asarray(depth, dtype=np.float32)[::stride, ::stride].reshape(-1)
    known = np.isfinite(d) & (d > 0) & (d <= max_depth)
    return camera.unproject(d[known], uv[known]) @ transform[:3, :3].T + transform[:3, 3]


@dataclass(frozen=True)
class _Grid:
    x0: float
    y0: float
    size: float
    nx: int
    ny: int

    @classmethod
    def covering(cls, xy: np.ndarray, size: float, margin: float) -> _Grid:
        lo, hi = xy.min(axis=0) - margin, xy.max(axis=0) + margin
        x0, y0 = math.floor(lo[0] / size) * size, math.floor(lo[1] / size) * size
        return cls(x0, y0, size, math.ceil((hi[0] - x0) / size) + 1, math.ceil((hi[1] - y0) / size) + 1)

    def hits(self, chunks: list[np.ndarray]) -> np.ndarray:
        """``(ny, nx)`` how many of the points fall in each cell."""
        xy = np.concatenate(chunks) if chunks else np.zeros((0, 2))
        col = np.floor((xy[:, 0] - self.x0) / self.size).astype(np.int64)
        row = np.floor((xy[:, 1] - self.y0) / self.size).astype(np.int64)
        inside = (col >= 0) & (col < self.nx) & (row >= 0) & (row < self.ny)
        return np.bincount(row[inside] * self.nx + col[inside], minlength=self.nx * self.ny).reshape(self.ny, self.nx)

    def polygons(self, mask: np.ndarray) -> BaseGeometry:
        return grid_polygons(mask, (self.x0, self.y0), self.size)


def _polygonal(geom: BaseGeometry) -> BaseGeometry:
    """Only the polygons of ``geom`` (buffers and differences can leave lines and points)."""
    parts = [p for p in shapely.get_parts(geom) if p.geom_type == "Polygon" and not p.is_empty]
    return shapely.union_all(parts) if parts else shapely.Polygon()
