"""A generated home as data: its config, rooms, labelled objects and floor plan, and what
one asks of it (its scene, object lookups, free poses, a view of an object).
:mod:`ssga_workspace_procedural.generator` builds it.

Frames and units are ssga's (:mod:`ssga_core.geometry`): metres, ``z`` up, floor at
``z = 0``; the house's outer south-west corner is the origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import shapely
import trimesh
from shapely.geometry import Polygon

from ssga_core import InputError, Pose
from ssga_bench import FloorPlan
from ssga_workspace_procedural import textures
from ssga_workspace_procedural.categories import semantic_id
from ssga_workspace_procedural.layout import Layout, Rect


@dataclass(frozen=True)
class HomeConfig:
    """Everything :func:`~ssga_workspace_procedural.generator.generate_home` needs; the same config always gives the same home.

    Attributes:
        seed: the random seed.
        rooms: number of rooms.
        width, depth: outer size of the house along ``x`` and ``y`` (metres).
        furniture_density: scales each recipe line's chance (0: empty rooms; 1: the
            recipes as written; 2: nearly everything that fits) and the number of paintings.
        wall_height, wall_thickness, door_width, door_height: the structure (metres).
        robot_radius: how far a standing camera keeps from walls and furniture.
        occluder_height: furniture at least this tall blocks the line of sight at camera
            height and joins the floor plan's occluders (1.2 m: below any standing
            camera, above tables, sofas and beds).
        min_room_side: no room is narrower than this (metres).
    """

    seed: int = 0
    rooms: int = 4
    width: float = 10.0
    depth: float = 8.0
    furniture_density: float = 1.0
    wall_height: float = 2.6
    wall_thickness: float = 0.12
    door_width: float = 0.9
    door_height: float = 2.1
    robot_radius: float = 0.25
    occluder_height: float = 1.2
    min_room_side: float = 2.4

    def __post_init__(self) -> None:
        if self.rooms < 1:
            raise InputError(f"HomeConfig.rooms: need at least one room, got {self.rooms}")
        if min(self.width, self.depth) < self.min_room_side:
            raise InputError(f"HomeConfig: a {self.width:g} x {self.depth:g} m home is smaller than one room")
        if not 0 < self.door_height < self.wall_height:
            raise InputError("HomeConfig: door_height must be between 0 and wall_height")
        if self.door_width <= 2 * self.robot_radius:
            raise InputError("HomeConfig: doors must be wider than the robot (door_width > 2 * robot_radius)")


@dataclass(frozen=True, eq=False)
class HomeObject:
    """One labelled geometry of the home.

    Attributes:
        name: ``"{category}-{instance_id:04d}"``, the geometry's name in scenes and exports.
        category: a key of :data:`~ssga_workspace_procedural.categories.CATEGORIES`.
        instance_id: unique in the home, from 1.
        mesh: in the world frame, textured or face-coloured.
        room: index of the room it belongs to; None for the outside of the outer walls.
        footprint: its outline on the floor for furniture; None for walls, floors,
            ceilings and wall-mounted paintings.
        height: the highest point above the floor (metres).
    """

    name: str
    category: str
    instance_id: int
    mesh: trimesh.Trimesh
    room: int | None
    footprint: Polygon | None = None
    height: float = 0.0

    @property
    def semantic_id(self) -> int:
        return semantic_id(self.category)

    @property
    def flat(self) -> bool:
        """A floor covering: other furniture may stand on it and it blocks nobody's way."""
        return self.footprint is not None and self.height < 0.05


@dataclass(frozen=True, eq=False)
class Room:
    """A room: its cell (to the wall centre lines), interior (to the wall faces) and surfaces."""

    index: int
    kind: str
    cell: Rect
    interior: Rect
    floor: textures.Texture
    wall: textures.Texture


@dataclass(frozen=True, eq=False)
class Home:
    """A generated home: structure, furniture and floor plan.

    Attributes:
        wall_parts: the footprint of each wall piece that reaches the floor (lintels
            over doorways excluded), hole-free rectangles.
        floor_plan: ``free`` is where a camera (a disc of ``config.robot_radius``) may
            stand, one polygon through the doorways; ``occluders`` is the union of
            :attr:`occluder_parts`.
    """

    config: HomeConfig
    layout: Layout
    rooms: tuple[Room, ...]
    objects: tuple[HomeObject, ...]
    wall_parts: tuple[Polygon, ...] = field(repr=False)
    floor_plan: FloorPlan

    @property
    def occluder_parts(self) -> list[Polygon]:
        """The occluders as separate hole-free polygons: each wall piece, then each piece of
        furniture at least ``config.occluder_height`` tall (what exports write)."""
        tall = [o.footprint for o in self.furniture if o.height >= self.config.occluder_height]
        return [*self.wall_parts, *tall]

    def __getitem__(self, name: str) -> HomeObject:
        for obj in self.objects:
            if obj.name == name:
                return obj
        raise KeyError(name)

    def of_category(self, category: str) -> list[HomeObject]:
        return [o for o in self.objects if o.category == category]

    @property
    def furniture(self) -> list[HomeObject]:
        """Objects standing on the floor (rugs included)."""
        return [o for o in self.objects if o.footprint is not None]

    def ids(self) -> dict[str, tuple[int, int]]:
        """Geometry name -> ``(semantic_id, instance_id)``, as the mesh renderer takes them."""
        return {o.name: (o.semantic_id, o.instance_id) for o in self.objects}

    @property
    def triangle_count(self) -> int:
        return sum(len(o.mesh.faces) for o in self.objects)

    @cached_property
    def scene(self) -> trimesh.Scene:
        """A trimesh scene of every object, in ssga's z-up world frame.

        Geometry and node names are the objects' names; each geometry's ``metadata``
        holds ``category``, ``semantic_id`` and ``instance_id``.
        """
        scene = trimesh.Scene()
        for obj in self.objects:
            mesh = obj.mesh.copy()
            mesh.metadata.update(category=obj.category, semantic_id=obj.semantic_id, instance_id=obj.instance_id, name=obj.name)
            scene.add_geometry(mesh, geom_name=obj.name, node_name=obj.name)
        return scene

    def sample_poses(self, count: int, rng: np.random.Generator, height: float = 1.5) -> list[Pose]:
        """``count`` poses drawn uniformly from the free floor, with uniform headings."""
        free = self.floor_plan.free
        x0, y0, x1, y1 = free.bounds
        poses: list[Pose] = []
        while len(poses) < count:
            x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
            if free.covers(shapely.Point(x, y)):
                poses.append(Pose(float(x), float(y), float(rng.uniform(-np.pi, np.pi)), height))
        return poses

    def view_of(self, name: str, height: float = 1.5, distances: tuple[float, ...] = (2.0, 2.5, 1.6, 3.0, 1.3)) -> Pose | None:
        """A free pose looking straight at object ``name`` with a clear line of sight, or None.

        Searches rings around the object's footprint centre (nearest ring first); the
        sight line must miss the occluders and every other piece of furniture that is
        not flat.
        """
        target = self[name]
        if target.footprint is None:
            raise InputError(f"view_of: {name!r} has no footprint to look at")
        c = target.footprint.centroid
        others = [o.footprint for o in self.furniture if o.name != name and not o.flat]
        blockers = shapely.union_all([self.floor_plan.occluders.difference(target.footprint), *others])
        for r in distances:
            for a in np.linspace(-np.pi, np.pi, 48, endpoint=False):
                x, y = c.x + r * np.cos(a), c.y + r * np.sin(a)
                if not self.floor_plan.can_stand(x, y):
                    continue
                sight = shapely.LineString([(x, y), (c.x, c.y)])
                if not sight.intersects(blockers):
                    return Pose(float(x), float(y), float(np.arctan2(c.y - y, c.x - x)), height)
        return None
