"""Workspaces: the scenes views come from.

A workspace source plugin (:class:`~ssga_core.stages.WorkspaceSource`) opens a
:class:`Workspace`; the benchmark protocol (cells, classes, view overlap) is applied to
it by the core, whatever the source.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

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
        A polygon without holes may also be given as just its outline.
        """
        return {name: [_rings(p) for p in _polygons(getattr(self, name))] for name in ("free", "occluders")}

    @classmethod
    def from_json(cls, data: Any, source: str = "floor plan") -> FloorPlan:
        try:
            parts = {name: shapely.union_all([_polygon(p) for p in data[name]]) for name in ("free", "occluders")}
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError(
                f"{source}: expected {{\"free\": [polygons], \"occluders\": [polygons]}} with polygons as lists of "
                f"[x, y] rings ({type(exc).__name__}: {exc})"
            ) from None
        return cls(free=parts["free"], occluders=parts["occluders"])


def _polygons(geom: BaseGeometry) -> list[shapely.Polygon]:
    return [g for g in getattr(geom, "geoms", [geom]) if g.geom_type == "Polygon" and not g.is_empty]


def _rings(poly: shapely.Polygon) -> list[list[list[float]]]:
    return [[[round(x, 6), round(y, 6)] for x, y in ring.coords] for ring in (poly.exterior, *poly.interiors)]


def _polygon(rings: Any) -> shapely.Polygon:
    if rings and isinstance(rings[0][0], (int, float)):  # just an outline
        rings = [rings]
    poly = shapely.Polygon(rings[0], rings[1:])
    return poly if poly.is_valid else poly.buffer(0)


@runtime_checkable
class CapturedWorkspace(Protocol):
    """A set of views captured by a robot or exported from a simulator; it cannot render new poses.

    The benchmark protocol selects its training and test views among the captures
    instead of sampling poses (:meth:`ssga_core.protocol.Protocol.select`).
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

    def render(self, pose: Pose) -> View:
        """The view from ``pose`` (RGB, and depth and semantic ids if the source has them)."""
        ...


AnyWorkspace = Workspace | CapturedWorkspace
