"""Workspaces: the scenes views come from.

A workspace source plugin (:class:`~ssga_core.stages.WorkspaceSource`) opens a
:class:`Workspace`; the benchmark protocol (cells, classes, view overlap) is applied to
it by the core, whatever the source.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from ssga_core.data import View
from ssga_core.errors import InputError
from ssga_core.geometry import Camera, Pose


@dataclass(frozen=True)
class FloorPlan:
    """A workspace seen from above, in world metres on the floor plane (``x``, ``y``).

    Attributes:
        free: where a camera may stand (the navigable floor, away from walls and furniture).
        occluders: what blocks the line of sight at camera height (walls, tall furniture),
            used for the visibility polygons of the view-overlap rate.
    """

    free: BaseGeometry
    occluders: BaseGeometry

    def __post_init__(self) -> None:
        for name in ("free", "occluders"):
            geom = getattr(self, name)
            if not isinstance(geom, BaseGeometry) or geom.geom_type not in ("Polygon", "MultiPolygon", "GeometryCollection"):
                raise InputError(f"FloorPlan.{name}: expected a shapely (Multi)Polygon, got {type(geom).__name__}")
        if self.free.is_empty:
            raise InputError("FloorPlan.free: the plan has no free floor to stand on")

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the free floor and the occluders together."""
        return shapely.union(self.free, self.occluders).bounds

    def can_stand(self, x: float, y: float) -> bool:
        return bool(self.free.covers(shapely.Point(x, y)))

    def to_json(self) -> dict[str, Any]:
        """The floor-plan file format: ``{"free": [...], "occluders": [...]}``.

        Each entry is a polygon as GeoJSON writes one: a list of rings, the outline first,
        then its holes, each ring a list of ``[x, y]`` in metres (ssga's world frame).
        A polygon without holes may also be given as just its outline. Where a camera
        may stand is the union of the ``free`` polygons less the ``occluders``, so
        furniture inside a room needs no hole; ``occluders`` may be left out.
        """
        return {name: [_rings(p) for p in _polygons(getattr(self, name))] for name in ("free", "occluders")}

    @classmethod
    def from_json(cls, data: Any, source: str = "floor plan") -> FloorPlan:
        """Read the :meth:`to_json` format; errors name ``source`` and the polygon at fault."""
        if not isinstance(data, dict) or "free" not in data:
            raise InputError(f'{source}: expected {{"free": [polygon, ...], "occluders": [polygon, ...]}}, polygons as lists of [x, y] rings')
        free = shapely.union_all(_read_polygons(source, "free", data["free"]))
        occluders = shapely.union_all(_read_polygons(source, "occluders", data.get("occluders", [])))
        free = free.difference(occluders)
        if free.is_empty:
            raise InputError(f"{source}: the free polygons leave no floor to stand on once the occluders are removed")
        return cls(free=free, occluders=occluders)


def grid_polygons(mask: np.ndarray, origin: tuple[float, float], size: float) -> BaseGeometry:
    """The union of the true cells of a grid mask as polygons: cell ``(row, col)`` spans
    ``origin + (col, row) * size`` to one ``size`` further, rows along ``y``. Built from one
    box per horizontal run of cells, so a whole house's grid unions in well under a second."""
    padded = np.zeros((mask.shape[0], mask.shape[1] + 2), dtype=np.int8)
    padded[:, 1:-1] = mask
    change = np.diff(padded, axis=1)
    rows, starts = np.nonzero(change == 1)
    _, ends = np.nonzero(change == -1)  # same row-major order as the starts
    if len(rows) == 0:
        return shapely.Polygon()
    x0, y0 = origin
    return shapely.union_all(shapely.box(x0 + starts * size, y0 + rows * size, x0 + ends * size, y0 + (rows + 1) * size))


def _polygons(geom: BaseGeometry) -> list[shapely.Polygon]:
    return [g for g in getattr(geom, "geoms", [geom]) if g.geom_type == "Polygon" and not g.is_empty]


def _rings(poly: shapely.Polygon) -> list[list[list[float]]]:
    return [[[round(x, 6), round(y, 6)] for x, y in ring.coords] for ring in (poly.exterior, *poly.interiors)]


def _read_polygons(source: str, key: str, value: Any) -> list[shapely.Polygon]:
    if not isinstance(value, list):
        raise InputError(f"{source}: {key!r} must be a list of polygons, each a list of [x, y] rings")
    out = []
    for i, item in enumerate(value):
        rings = [item] if isinstance(item, list) and item and _is_point(item[0]) else item
        arrays = []
        for ring in rings if isinstance(rings, list) else [None]:
            try:
                coords = np.asarray(ring, dtype=np.float64)
            except (TypeError, ValueError):
                coords = np.empty((0,))
            if coords.ndim != 2 or coords.shape[1] != 2 or len(coords) < 3 or not np.isfinite(coords).all():
                raise InputError(f"{source}: {key}[{i}] must be a ring of at least 3 [x, y] points in metres, or a list of such rings")
            arrays.append(coords)
        polygon = shapely.Polygon(arrays[0], arrays[1:])
        if not polygon.is_valid or polygon.area == 0:
            raise InputError(f"{source}: {key}[{i}] is not a simple polygon ({shapely.is_valid_reason(polygon)})")
        out.append(polygon)
    return out


def _is_point(value: Any) -> bool:
    return isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value)


@runtime_checkable
class CapturedWorkspace(Protocol):
    """A set of views captured by a robot or exported from a simulator; it cannot render new poses.

    The benchmark protocol selects its training and test views among the captures
    instead of sampling poses (:meth:`ssga_bench.protocol.Protocol.select`).
    """

    name: str
    camera: Camera
    floor_plan: FloorPlan
    captures: Sequence[Pose]
    """The pose of each captured view."""

    def load(self, index: int) -> View:
        """The captured view ``index`` (RGB; depth and semantic ids where captured)."""
        ...


@runtime_checkable
class Workspace(Protocol):
    """A scene that can show what a camera at any pose sees."""

    name: str
    camera: Camera
    floor_plan: FloorPlan
    camera_height: float
    """Height above the floor of the robot's camera: the protocol's viewpoints stand there."""

    def render(self, pose: Pose) -> View:
        """The view from ``pose`` (RGB, and depth and semantic ids if the source has them)."""
        ...


AnyWorkspace = Workspace | CapturedWorkspace
