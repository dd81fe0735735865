"""Workspaces: the scenes views come from.

A workspace source plugin (:class:`~ssga_core.stages.WorkspaceSource`) opens a
:class:`Workspace`; the benchmark protocol (cells, classes, view overlap) is applied to
it by the core, whatever the source.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

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


@runtime_checkable
class Workspace(Protocol):
    """A scene that can show what a camera at any pose sees."""

    name: str
    camera: Camera
    floor_plan: FloorPlan

    def render(self, pose: Pose) -> View:
        """The view from ``pose`` (RGB, and depth and semantic ids if the source has them)."""
        ...
