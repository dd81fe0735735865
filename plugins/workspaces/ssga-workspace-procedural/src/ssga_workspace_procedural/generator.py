"""Generating seeded multi-room homes: layout, surfaces, furniture, paintings and the floor
plan (the result, :class:`~ssga_workspace_procedural.home.Home`, is in :mod:`.home`).

:func:`generate_home` is deterministic: the same :class:`HomeConfig` gives
byte-identical geometry, textures and ids, whatever the platform or the Python hash
seed. Independent parts of the home draw from independent streams spawned from the
seed (layout, surfaces, furniture, paintings), so that, say, a change to furniture
recipes does not move the walls.

Frames and units are ssga's (:mod:`ssga_core.geometry`): metres, ``z`` up, floor at
``z = 0``; the house's outer south-west corner is the origin.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import shapely
import trimesh
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from ssga_bench import FloorPlan
from ssga_workspace_procedural import textures
from ssga_workspace_procedural.arrangements import RECIPES, Arrangement, Placement, turn, turned_size
from ssga_workspace_procedural.home import Home, HomeConfig, HomeObject, Room
from ssga_workspace_procedural.layout import SIDES, Door, Layout, Rect, Side, WallPiece, make_layout, room_walls, shell_walls
from ssga_workspace_procedural.meshes import merge_textured, place, textured_box

DOOR_CLEARANCE = 0.9
"""Floor kept free of furniture in front of each doorway (metres, each side)."""

MIN_POCKET = 0.05
"""Free-space components smaller than this (m^2) are slivers, dropped from the plan; larger ones must not be cut off."""



# --- free space -------------------------------------------------------------------------


PAINTING_SPACING = 8.0
"""At density 1, a room gets one painting per this many metres of wall (if they fit)."""

QUAD_SEGS = 4
"""Segments per quarter circle when buffering by the robot's radius."""


class FreeSpace:
    """Where a camera of ``radius`` may stand, given the walls and the furniture so far.

    Buffers approximate circular arcs by chords, which cut inside the arc; the radius
    is enlarged so that the chords' midpoints are ``radius`` away, which keeps every
    free point at least ``radius`` from walls and furniture.
    """

    def __init__(self, walkable: BaseGeometry, radius: float) -> None:
        self.radius = radius / np.cos(np.pi / (4 * QUAD_SEGS))
        self.base = walkable.buffer(-self.radius, quad_segs=QUAD_SEGS)
        self.blocked: list[BaseGeometry] = []

    def _grow(self, footprint: BaseGeometry) -> BaseGeometry:
        return footprint.buffer(self.radius, quad_segs=QUAD_SEGS)

    def components(self, extra: list[BaseGeometry] = ()) -> list[Polygon]:
        """The connected pieces of free floor, largest first, with ``extra`` footprints also blocked."""
        free = self.base.difference(shapely.union_all(self.blocked + [self._grow(f) for f in extra]))
        parts = [g for g in getattr(free, "geoms", [free]) if g.area > 1e-9]
        return sorted(parts, key=lambda p: -p.area)

    def stays_connected(self, footprints: list[BaseGeometry]) -> bool:
        """Whether blocking ``footprints`` too would leave one free component (bar slivers)."""
        return sum(p.area >= MIN_POCKET for p in self.components(footprints)) == 1

    def block(self, footprints: list[BaseGeometry]) -> None:
        self.blocked.extend(self._grow(f) for f in footprints)

    def polygon(self) -> Polygon:
        """The free floor: the largest component (the others are slivers by construction)."""
        return self.components()[0]


# --- generation -------------------------------------------------------------------------


class _Builder:
    """Accumulates objects with consecutive instance ids."""

    def __init__(self) -> None:
        self.objects: list[HomeObject] = []

    def add(
        self,
        category: str,
        mesh: trimesh.Trimesh,
        room: int | None,
        footprint: Polygon | None = None,
        height: float | None = None,
    ) -> HomeObject:
        iid = len(self.objects) + 1
        top = float(mesh.bounds[1, 2]) if height is None else height
        obj = HomeObject(f"{category}-{iid:04d}", category, iid, mesh, room, footprint, round(top, 6))
        self.objects.append(obj)
        return obj


def _assign_kinds(cells: tuple[Rect, ...], rng: np.random.Generator) -> list[str]:
    """The largest room is the living room; the others, in random order, a kitchen, then bedrooms and offices.

    One kitchen per home until there are eight rooms, when the eighth becomes a second living room.
    """
    order = sorted(range(len(cells)), key=lambda i: (-cells[i].area, i))
    others = [int(i) for i in rng.permutation(order[1:])] if len(order) > 1 else []
    kinds = ["living"] * len(cells)
    cycle = ("kitchen", "bedroom", "office", "bedroom", "office", "bedroom", "living")
    for rank, i in enumerate(others):
        kinds[i] = cycle[rank % len(cycle)]
    return kinds


def _piece_box(piece: WallPiece, texture: textures.Texture) -> trimesh.Trimesh:
    r = piece.rect
    faces = [f for f in ("+x", "-x", "+y", "-y", "+z", "-z") if not (f == "-z" and piece.full)]
    return textured_box((r.x0, r.y0, piece.z0), (r.x1, r.y1, piece.z1), texture, faces)


def _structure(b: _Builder, layout: Layout, rooms: list[Room], cfg: HomeConfig, rng: np.random.Generator) -> list[Polygon]:
    """Walls, floors and ceilings; returns the footprints of the full-height wall pieces."""
    half = cfg.wall_thickness / 2.0
    full: list[Polygon] = []
    for room in rooms:
        pieces = room_walls(room.cell, layout.doors_of(room.index), half, cfg.wall_height, cfg.door_height)
        b.add("wall", merge_textured([_piece_box(p, room.wall) for p in pieces], room.wall), room.index)
        full += [p.rect.polygon() for p in pieces if p.full]
    shell = shell_walls(layout.outer, half, cfg.wall_height)
    facade = textures.facade(rng)
    b.add("wall", merge_textured([_piece_box(p, facade) for p in shell], facade), None)
    full += [p.rect.polygon() for p in shell]
    ceiling = textures.ceiling(rng)
    for room in rooms:
        c = room.cell
        b.add("floor", textured_box((c.x0, c.y0, -0.02), (c.x1, c.y1, 0.0), room.floor, ("+z",)), room.index)
        b.add(
            "ceiling",
            textured_box((c.x0, c.y0, cfg.wall_height), (c.x1, c.y1, cfg.wall_height + 0.02), ceiling, ("-z",)),
            room.index,
        )
    return full


@dataclass
class _RoomState:
    """What is already in a room while furnishing it."""

    room: Room
    keep_clear: BaseGeometry
    solid: list[tuple[Polygon, float]] = field(default_factory=list)  # footprint, height
    flat: list[Polygon] = field(default_factory=list)
    wall_art: list[Polygon] = field(default_factory=list)


WALL_TURNS: dict[Side, int] = {"north": 0, "west": 1, "south": 2, "east": 3}
"""Quarter turns that put a model's back (``+y``) against each side's wall."""


def _candidates(
    interior: Rect, a: Arrangement, where: Placement, rng: np.random.Generator, tries: int
) -> Iterator[tuple[float, float, int]]:
    """Random ``(x, y, quarter_turns)`` for an arrangement in a room, per placement rule."""
    gap = 0.01
    for _ in range(tries):
        if where == "center":
            turns = int(rng.integers(4))
            w, d = turned_size(a.width, a.depth, turns)
            m = 0.3
            if interior.width < w + 2 * m or interior.depth < d + 2 * m:
                return
            yield (
                float(rng.uniform(interior.x0 + m + w / 2, interior.x1 - m - w / 2)),
                float(rng.uniform(interior.y0 + m + d / 2, interior.y1 - m - d / 2)),
                turns,
            )
            continue
        side = SIDES[int(rng.integers(4))]
        turns = WALL_TURNS[side]
        w, d = turned_size(a.width, a.depth, turns)
        if w > interior.width - 2 * gap or d > interior.depth - 2 * gap:
            continue
        if side in ("north", "south"):
            y = interior.y1 - gap - d / 2 if side == "north" else interior.y0 + gap + d / 2
            if where == "corner":
                x = interior.x0 + gap + w / 2 if rng.random() < 0.5 else interior.x1 - gap - w / 2
            else:
                x = float(rng.uniform(interior.x0 + gap + w / 2, interior.x1 - gap - w / 2))
        else:
            x = interior.x1 - gap - w / 2 if side == "east" else interior.x0 + gap + w / 2
            if where == "corner":
                y = interior.y0 + gap + d / 2 if rng.random() < 0.5 else interior.y1 - gap - d / 2
            else:
                y = float(rng.uniform(interior.y0 + gap + d / 2, interior.y1 - gap - d / 2))
        yield round(float(x), 4), round(float(y), 4), turns


def _footprints(a: Arrangement, x: float, y: float, turns: int) -> list[tuple[Polygon, int]]:
    """Each member's world footprint (an axis-aligned rectangle) and its total quarter turns."""
    out = []
    for m in a.members:
        dx, dy = turn(m.x, m.y, turns)
        w, d = turned_size(m.model.width, m.model.depth, m.turns + turns)
        cx, cy = x + dx, y + dy
        out.append((shapely.box(cx - w / 2, cy - d / 2, cx + w / 2, cy + d / 2), m.turns + turns))
    return out


def _fits(state: _RoomState, a: Arrangement, prints: list[tuple[Polygon, int]], free: FreeSpace) -> bool:
    inside = state.room.interior.polygon()
    solid = [p for (p, _), m in zip(prints, a.members, strict=True) if not m.model.flat]
    flat = [p for (p, _), m in zip(prints, a.members, strict=True) if m.model.flat]
    for p in solid + flat:
        if not inside.contains(p) or p.intersects(state.keep_clear):
            return False
    spaced = [p.buffer(0.05, join_style="mitre") for p in solid]
    if any(s.intersects(q) for s in spaced for q, _ in state.solid):
        return False
    if any(f.intersects(q) for f in flat for q in state.flat):
        return False
    return free.stays_connected(solid)


def _furnish(b: _Builder, state: _RoomState, free: FreeSpace, density: float, rng: np.random.Generator) -> None:
    for recipe in RECIPES[state.room.kind]:
        if rng.random() >= min(1.0, recipe.chance * density):
            continue
        a = recipe.build(rng)
        for x, y, turns in _candidates(state.room.interior, a, recipe.where, rng, tries=40):
            prints = _footprints(a, x, y, turns)
            if not _fits(state, a, prints, free):
                continue
            for m, (footprint, total_turns) in zip(a.members, prints, strict=True):
                c = footprint.centroid
                mesh = place(m.model.mesh, round(c.x, 6), round(c.y, 6), total_turns)
                b.add(m.model.category, mesh, state.room.index, footprint, m.model.height)
                if m.model.flat:
                    state.flat.append(footprint)
                else:
                    state.solid.append((footprint, m.model.height))
                    free.block([footprint])
            break


FRONT_FACE: dict[Side, str] = {"north": "-y", "south": "+y", "west": "+x", "east": "-x"}
"""The face of a wall-hung box that looks into the room, for each wall."""

BACK_FACE: dict[str, str] = {"-y": "+y", "+y": "-y", "+x": "-x", "-x": "+x"}

ART_REACH = 0.3
"""Depth in front of a painting that must be free of furniture taller than the painting's bottom edge."""


def _against_wall(
    r: Rect, side: Side, centre: float, width: float, depth: float
) -> tuple[tuple[float, float], tuple[float, float]]:
    """``((x0, x1), (y0, y1))`` of a span ``width`` wide centred at ``centre`` along ``side``'s wall, ``depth`` into the room."""
    span = (centre - width / 2, centre + width / 2)
    if side == "north":
        return span, (r.y1 - depth, r.y1)
    if side == "south":
        return span, (r.y0, r.y0 + depth)
    if side == "west":
        return (r.x0, r.x0 + depth), span
    return (r.x1 - depth, r.x1), span


def _hang_paintings(
    b: _Builder, state: _RoomState, doors: list[Door], count: int, posters: deque[str], rng: np.random.Generator
) -> None:
    """Framed photographs on the walls, clear of doors, of each other and of tall furniture in front.

    ``posters`` is the home's shuffled queue of photographs; a hung one goes to the
    back, so a photograph repeats only once all have been used.
    """
    r = state.room.interior
    near_doors = shapely.union_all([d.clearance(DOOR_CLEARANCE, 0.15) for d in doors])
    for _ in range(count):
        for _attempt in range(20):
            side = SIDES[int(rng.integers(4))]
            art = textures.poster(posters[0], textures.jitter(rng, (0.12, 0.1, 0.08), 0.1))
            scale = round(float(rng.uniform(0.5, 1.1)), 2)
            w, h = round(art.size[0] * scale, 4), round(art.size[1] * scale, 4)
            z0 = round(float(rng.uniform(1.45, 1.6)) - h / 2, 4)
            lo, hi = (r.x0, r.x1) if side in ("north", "south") else (r.y0, r.y1)
            if hi - lo < w + 0.4:
                continue
            centre = round(float(rng.uniform(lo + 0.2 + w / 2, hi - 0.2 - w / 2)), 4)
            (sx0, sx1), (sy0, sy1) = _against_wall(r, side, centre, w, ART_REACH)
            strip = shapely.box(sx0, sy0, sx1, sy1)
            if strip.intersects(near_doors) or any(strip.intersects(p) for p in state.wall_art):
                continue
            if any(strip.intersects(p) and height > z0 - 0.05 for p, height in state.solid):
                continue
            (x0, x1), (y0, y1) = _against_wall(r, side, centre, w, 0.03)
            front = FRONT_FACE[side]
            faces = [f for f in ("+x", "-x", "+y", "-y", "+z", "-z") if f != BACK_FACE[front]]
            b.add("painting", textured_box((x0, y0, z0), (x1, y1, z0 + h), art, faces, fit=front), state.room.index)
            state.wall_art.append(strip)
            posters.rotate(-1)
            break


def generate_home(config: HomeConfig | None = None) -> Home:
    """Generate the home ``config`` describes (deterministically)."""
    cfg = config or HomeConfig()
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(cfg.seed).spawn(4)]
    layout_rng, surface_rng, furniture_rng, art_rng = streams
    half = cfg.wall_thickness / 2.0
    layout = make_layout(
        cfg.width, cfg.depth, cfg.rooms, layout_rng,
        min_side=cfg.min_room_side, door_width=cfg.door_width, door_margin=cfg.wall_thickness + 0.15,
    )  # fmt: skip
    kinds = _assign_kinds(layout.cells, layout_rng)
    rooms = []
    for i, (cell, kind) in enumerate(zip(layout.cells, kinds, strict=True)):
        floor, wall = textures.room_surfaces(surface_rng, kind)
        rooms.append(Room(i, kind, cell, cell.shrink(half), floor, wall))

    b = _Builder()
    wall_prints = _structure(b, layout, rooms, cfg, surface_rng)

    openings = [d.opening(cfg.wall_thickness) for d in layout.doors]
    free = FreeSpace(shapely.union_all([r.interior.polygon() for r in rooms] + openings), cfg.robot_radius)
    door_zone = shapely.union_all([d.clearance(DOOR_CLEARANCE, 0.1) for d in layout.doors]) if layout.doors else shapely.Polygon()
    states = [_RoomState(room, door_zone) for room in rooms]
    for state in states:
        _furnish(b, state, free, cfg.furniture_density, furniture_rng)
    posters = deque(textures.POSTERS[int(i)] for i in art_rng.permutation(len(textures.POSTERS)))
    for state in states:
        r = state.room.interior
        count = round(cfg.furniture_density * 2 * (r.width + r.depth) / PAINTING_SPACING)
        _hang_paintings(b, state, layout.doors_of(state.room.index), count, posters, art_rng)

    tall = [o.footprint for o in b.objects if o.footprint is not None and o.height >= cfg.occluder_height]
    plan = FloorPlan(free=free.polygon(), occluders=shapely.union_all(wall_prints + tall))
    return Home(cfg, layout, tuple(rooms), tuple(b.objects), tuple(wall_prints), plan)
