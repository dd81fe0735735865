"""Rectilinear floor plans: rooms by recursive splitting, doors along a spanning tree.

Pure 2-D geometry in world metres (``x``, ``y``); no meshes. The house is the
rectangle ``outer``; splitting it gives the *cells*, whose shared edges are the wall
centre lines. Each room's walls are a ring of half the wall thickness just inside its
cell, so a wall between two rooms is made of two halves, one per room, and each side
can carry its own room's texture.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import shapely
from shapely.geometry import Polygon

from ssga_core import InputError

Side = Literal["south", "north", "west", "east"]
"""A side of a room: ``south`` is its ``y = y0`` edge, ``north`` ``y = y1``, ``west`` ``x = x0``, ``east`` ``x = x1``."""

SIDES: tuple[Side, ...] = ("south", "north", "west", "east")

GRID = 0.05
"""Split lines and doors are snapped to this grid (metres), so plans are tidy and exact."""


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle ``[x0, x1] x [y0, y1]``."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def width(self) -> float:
        return self.x1 - self.x0

    @property
    def depth(self) -> float:
        return self.y1 - self.y0

    @property
    def area(self) -> float:
        return self.width * self.depth

    @property
    def center(self) -> tuple[float, float]:
        return ((self.x0 + self.x1) / 2.0, (self.y0 + self.y1) / 2.0)

    def shrink(self, d: float) -> Rect:
        return Rect(self.x0 + d, self.y0 + d, self.x1 - d, self.y1 - d)

    def polygon(self) -> Polygon:
        return shapely.box(self.x0, self.y0, self.x1, self.y1)


@dataclass(frozen=True)
class Door:
    """A doorway in the wall between two rooms.

    Attributes:
        rooms: the two rooms' indices, lower first.
        along: ``"x"`` if the wall runs along ``x`` (at ``y = at``), ``"y"`` if along ``y`` (at ``x = at``).
        at: the wall's centre line.
        lo, hi: the opening's extent along the wall.
    """

    rooms: tuple[int, int]
    along: Literal["x", "y"]
    at: float
    lo: float
    hi: float

    def opening(self, thickness: float) -> Polygon:
        """The opening's footprint through a wall of ``thickness``."""
        return self.clearance(thickness / 2.0, 0.0)

    def clearance(self, depth: float, margin: float) -> Polygon:
        """The floor ``depth`` either side of the wall's centre line, ``margin`` wider than the opening, kept clear of furniture."""
        if self.along == "x":
            return shapely.box(self.lo - margin, self.at - depth, self.hi + margin, self.at + depth)
        return shapely.box(self.at - depth, self.lo - margin, self.at + depth, self.hi + margin)

    def side_of(self, cell: Rect) -> Side:
        """Which side of ``cell`` (one of the two rooms) this door is on."""
        if self.along == "x":
            return "north" if np.isclose(cell.y1, self.at) else "south"
        return "east" if np.isclose(cell.x1, self.at) else "west"


@dataclass(frozen=True)
class Layout:
    """The house outline, its rooms' cells and the doors between them."""

    outer: Rect
    cells: tuple[Rect, ...]
    doors: tuple[Door, ...]

    def doors_of(self, room: int) -> list[Door]:
        return [d for d in self.doors if room in d.rooms]


def _snap(v: float) -> float:
    return round(round(v / GRID) * GRID, 6)


SPLIT_ATTEMPTS = 50
"""Fresh tries at splitting before a home is declared too small for its rooms."""


def split_cells(outer: Rect, rooms: int, rng: np.random.Generator, min_side: float) -> list[Rect]:
    """Cut ``outer`` into ``rooms`` cells by repeatedly splitting a cell across its longer side.

    The cell to split is drawn with probability proportional to its squared area, so
    big cells tend to be split and rooms come out of similar size; the cut falls in
    the middle 30-70 % where it can and leaves both parts at least ``min_side`` wide.
    Random cuts can paint themselves into a corner (cells too narrow to split again),
    so the whole sequence is retried with fresh draws before giving up.
    """
    for _ in range(SPLIT_ATTEMPTS):
        cells = _try_split(outer, rooms, rng, min_side)
        if cells is not None:
            # A stable order (south-west first) so a room's index says where it is.
            return sorted(cells, key=lambda c: (c.y0, c.x0))
    raise InputError(f"a {outer.width:g} x {outer.depth:g} m home cannot hold {rooms} rooms of at least {min_side:g} m a side")


def _try_split(outer: Rect, rooms: int, rng: np.random.Generator, min_side: float) -> list[Rect] | None:
    cells = [outer]
    for _ in range(rooms - 1):
        splittable = [i for i, c in enumerate(cells) if max(c.width, c.depth) >= 2 * min_side + 2 * GRID]
        if not splittable:
            return None
        weights = np.array([cells[i].area ** 2 for i in splittable])
        cell = cells.pop(splittable[int(rng.choice(len(splittable), p=weights / weights.sum()))])
        along_x = cell.width > cell.depth if abs(cell.width - cell.depth) > 0.5 else bool(rng.integers(2))
        if min(cell.width, cell.depth) < 2 * min_side + 2 * GRID:  # only the long side can take a cut
            along_x = cell.width >= cell.depth
        length = cell.width if along_x else cell.depth
        lo = min(0.5, max(0.3, (min_side + GRID) / length))
        t = rng.uniform(lo, 1.0 - lo)
        if along_x:
            cut = _snap(cell.x0 + t * length)
            cells += [Rect(cell.x0, cell.y0, cut, cell.y1), Rect(cut, cell.y0, cell.x1, cell.y1)]
        else:
            cut = _snap(cell.y0 + t * length)
            cells += [Rect(cell.x0, cell.y0, cell.x1, cut), Rect(cell.x0, cut, cell.x1, cell.y1)]
    return cells


def _shared_edge(a: Rect, b: Rect) -> tuple[Literal["x", "y"], float, float, float] | None:
    """The edge ``a`` and ``b`` share, as ``(along, at, lo, hi)``, or None."""
    for at in (a.y1,) if a.y1 == b.y0 else (a.y0,) if a.y0 == b.y1 else ():
        lo, hi = max(a.x0, b.x0), min(a.x1, b.x1)
        if hi > lo:
            return ("x", at, lo, hi)
    for at in (a.x1,) if a.x1 == b.x0 else (a.x0,) if a.x0 == b.x1 else ():
        lo, hi = max(a.y0, b.y0), min(a.y1, b.y1)
        if hi > lo:
            return ("y", at, lo, hi)
    return None


def place_doors(cells: list[Rect], rng: np.random.Generator, width: float, margin: float, extra: float = 0.25) -> list[Door]:
    """Doors that join every room: a random spanning tree of the adjacency, plus a few loops.

    A door needs a shared edge at least ``width + 2 * margin`` long (``margin`` keeps it
    off the corners); each extra adjacency gets a door with probability ``extra``.
    """
    edges = []
    for i in range(len(cells)):
        for j in range(i + 1, len(cells)):
            shared = _shared_edge(cells[i], cells[j])
            if shared is not None and shared[3] - shared[2] >= width + 2 * margin:
                edges.append((i, j, shared))
    order = rng.permutation(len(edges))
    parent = list(range(len(cells)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    doors = []
    for k in order:
        i, j, (along, at, lo, hi) = edges[int(k)]
        joins = root(i) != root(j)
        if joins:
            parent[root(i)] = root(j)
        if joins or rng.random() < extra:
            start = _snap(rng.uniform(lo + margin, hi - margin - width))
            doors.append(Door((i, j), along, at, start, round(start + width, 6)))
    if len({root(i) for i in range(len(cells))}) > 1:
        raise InputError("the rooms could not all be joined by doors; try a larger home or fewer rooms")
    return sorted(doors, key=lambda d: (d.rooms, d.lo))


def make_layout(
    width: float, depth: float, rooms: int, rng: np.random.Generator, *, min_side: float, door_width: float, door_margin: float
) -> Layout:
    """A ``width`` x ``depth`` house with its south-west outer corner at the origin."""
    outer = Rect(0.0, 0.0, _snap(width), _snap(depth))
    cells = split_cells(outer, rooms, rng, min_side)
    doors = place_doors(cells, rng, door_width, door_margin)
    return Layout(outer, tuple(cells), tuple(doors))


@dataclass(frozen=True)
class WallPiece:
    """A box of wall: its footprint ``rect`` and its vertical extent; ``full`` if it reaches the floor."""

    rect: Rect
    z0: float
    z1: float

    @property
    def full(self) -> bool:
        return self.z0 <= 0.0


def _side_rect(cell: Rect, side: Side, h: float) -> tuple[Rect, Literal["x", "y"]]:
    """The strip of ``cell``'s wall ring on ``side`` (east/west strips stop short of the corners)."""
    if side == "south":
        return Rect(cell.x0, cell.y0, cell.x1, cell.y0 + h), "x"
    if side == "north":
        return Rect(cell.x0, cell.y1 - h, cell.x1, cell.y1), "x"
    if side == "west":
        return Rect(cell.x0, cell.y0 + h, cell.x0 + h, cell.y1 - h), "y"
    return Rect(cell.x1 - h, cell.y0 + h, cell.x1, cell.y1 - h), "y"


def room_walls(cell: Rect, doors: list[Door], half: float, height: float, door_height: float) -> list[WallPiece]:
    """The pieces of a room's wall ring (``half`` thick), cut open at its doors.

    A door leaves a gap in the strip from the floor to ``door_height`` and a lintel
    above it.
    """
    pieces = []
    for side in SIDES:
        strip, along = _side_rect(cell, side, half)
        cuts = sorted((d.lo, d.hi) for d in doors if d.side_of(cell) == side)
        start = strip.x0 if along == "x" else strip.y0
        end = strip.x1 if along == "x" else strip.y1
        spans = []
        for lo, hi in cuts:
            spans.append((start, lo, 0.0))
            spans.append((lo, hi, door_height))
            start = hi
        spans.append((start, end, 0.0))
        for a, b, z0 in spans:
            if b - a <= 1e-9:
                continue
            rect = Rect(a, strip.y0, b, strip.y1) if along == "x" else Rect(strip.x0, a, strip.x1, b)
            pieces.append(WallPiece(rect, z0, height))
    return pieces


def shell_walls(outer: Rect, half: float, height: float) -> list[WallPiece]:
    """The outer half of the exterior walls: a ring ``half`` thick just outside ``outer``."""
    ring = outer.shrink(-half)
    return [WallPiece(r, 0.0, height) for r in (_side_rect(ring, s, half)[0] for s in SIDES)]
