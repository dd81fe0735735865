"""Arrangements: furniture that is placed together (a sofa with its coffee table and rug).

An arrangement is a few models at fixed offsets in a shared frame with the same
conventions as a single model (footprint centred on the origin, back towards ``+y``),
so the generator places a dining set exactly as it places a lone plant. Each room kind
has a recipe: which arrangements it may hold, where (against a wall, in a corner, in
the middle) and how likely each is.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ssga_workspace_procedural import furniture
from ssga_workspace_procedural.furniture import Model

Placement = Literal["wall", "corner", "center"]


def turn(x: float, y: float, quarter_turns: int) -> tuple[float, float]:
    """``(x, y)`` turned by ``quarter_turns`` x 90 degrees counter-clockwise, exactly."""
    q = quarter_turns % 4
    return ((x, y), (-y, x), (-x, -y), (y, -x))[q]


def turned_size(width: float, depth: float, quarter_turns: int) -> tuple[float, float]:
    return (width, depth) if quarter_turns % 2 == 0 else (depth, width)


@dataclass(frozen=True, eq=False)
class Member:
    """A model at ``(x, y)`` in its arrangement's frame, turned by ``turns`` quarter turns."""

    model: Model
    x: float
    y: float
    turns: int = 0

    def bounds(self) -> tuple[float, float, float, float]:
        w, d = turned_size(self.model.width, self.model.depth, self.turns)
        return (self.x - w / 2, self.y - d / 2, self.x + w / 2, self.y + d / 2)


@dataclass(frozen=True, eq=False)
class Arrangement:
    """Models placed together; :func:`arrangement` centres their bounding box on the origin."""

    members: tuple[Member, ...]
    width: float
    depth: float


def arrangement(*members: Member) -> Arrangement:
    """An arrangement of ``members``, shifted so their joint bounding box is centred on the origin."""
    b = np.array([m.bounds() for m in members])
    x0, y0, x1, y1 = b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    moved = tuple(Member(m.model, round(m.x - cx, 6), round(m.y - cy, 6), m.turns) for m in members)
    return Arrangement(moved, round(float(x1 - x0), 6), round(float(y1 - y0), 6))


def single(build: Callable[[np.random.Generator], Model]) -> Callable[[np.random.Generator], Arrangement]:
    return lambda rng: arrangement(Member(build(rng), 0.0, 0.0))


GAP = 0.02
"""Space left between pieces of an arrangement, so their footprints never touch."""


def lounge(rng: np.random.Generator) -> Arrangement:
    """A sofa facing a coffee table, often on a rug."""
    sofa = furniture.sofa(rng)
    table = furniture.table(rng, "coffee")
    ty = -(sofa.depth / 2 + 0.45 + table.depth / 2)
    members = [Member(sofa, 0.0, 0.0), Member(table, 0.0, ty)]
    if rng.random() < 0.7:
        rug = furniture.rug(rng, table.width + 0.8, table.depth + 0.7)
        members.append(Member(rug, 0.0, ty))
    return arrangement(*members)


def dining(rng: np.random.Generator) -> Arrangement:
    """A dining table with chairs along its long sides (and sometimes at its ends)."""
    table = furniture.table(rng, "dining")
    members = [Member(table, 0.0, 0.0)]
    per_side = max(1, int(table.width / 0.6))
    for side in (-1, 1):
        for i in range(per_side):
            x = -table.width / 2 + (i + 0.5) * table.width / per_side
            chair = furniture.chair(rng)
            y = side * (table.depth / 2 + GAP + chair.depth / 2)
            members.append(Member(chair, x, y, 0 if side > 0 else 2))
    if rng.random() < 0.4:
        for side in (-1, 1):
            chair = furniture.chair(rng)
            x = side * (table.width / 2 + GAP + chair.depth / 2)
            members.append(Member(chair, x, 0.0, 3 if side > 0 else 1))
    return arrangement(*members)


def desk(rng: np.random.Generator) -> Arrangement:
    """A desk against the wall and a chair pulled up to it."""
    table = furniture.table(rng, "desk")
    chair = furniture.chair(rng)
    return arrangement(Member(table, 0.0, 0.0), Member(chair, 0.0, -(table.depth / 2 + 0.1 + chair.depth / 2), 2))


def bedroom_set(rng: np.random.Generator) -> Arrangement:
    """A bed with a nightstand on one or both sides and sometimes a rug under its foot."""
    bed = furniture.bed(rng)
    members = [Member(bed, 0.0, 0.0)]
    sides = (-1, 1) if rng.random() < 0.6 else ((-1,) if rng.random() < 0.5 else (1,))
    for side in sides:
        stand = furniture.table(rng, "nightstand")
        members.append(Member(stand, side * (bed.width / 2 + GAP + stand.width / 2), bed.depth / 2 - stand.depth / 2))
    if rng.random() < 0.5:
        rug = furniture.rug(rng, bed.width + 0.9, 1.4)
        members.append(Member(rug, 0.0, -bed.depth / 2 + 0.4))
    return arrangement(*members)


@dataclass(frozen=True)
class Recipe:
    """One line of a room recipe: what to build, where it goes, and how likely it is (before density)."""

    build: Callable[[np.random.Generator], Arrangement]
    where: Placement
    chance: float


RECIPES: dict[str, tuple[Recipe, ...]] = {
    "living": (
        Recipe(lounge, "wall", 1.0),
        Recipe(single(furniture.shelf), "wall", 0.8),
        Recipe(single(lambda rng: furniture.cabinet(rng, tall=False)), "wall", 0.5),
        Recipe(single(furniture.armchair), "corner", 0.5),
        Recipe(single(furniture.plant), "corner", 0.8),
        Recipe(single(furniture.lamp), "corner", 0.7),
        Recipe(single(furniture.plant), "corner", 0.4),
    ),
    "bedroom": (
        Recipe(bedroom_set, "wall", 1.0),
        Recipe(single(lambda rng: furniture.cabinet(rng, tall=True)), "wall", 0.9),
        Recipe(desk, "wall", 0.3),
        Recipe(single(furniture.shelf), "wall", 0.3),
        Recipe(single(furniture.plant), "corner", 0.5),
        Recipe(single(furniture.lamp), "corner", 0.5),
    ),
    "kitchen": (
        Recipe(single(lambda rng: furniture.cabinet(rng, tall=False)), "wall", 1.0),
        Recipe(single(lambda rng: furniture.cabinet(rng, tall=False)), "wall", 0.6),
        Recipe(dining, "center", 0.9),
        Recipe(single(lambda rng: furniture.cabinet(rng, tall=True)), "wall", 0.4),
        Recipe(single(furniture.shelf), "wall", 0.3),
        Recipe(single(furniture.plant), "corner", 0.5),
    ),
    "office": (
        Recipe(desk, "wall", 1.0),
        Recipe(single(furniture.shelf), "wall", 0.9),
        Recipe(single(furniture.shelf), "wall", 0.5),
        Recipe(single(lambda rng: furniture.cabinet(rng, tall=False)), "wall", 0.4),
        Recipe(
            single(
                lambda rng: furniture.rug(rng, round(float(rng.uniform(1.2, 2.0)), 2), round(float(rng.uniform(1.0, 1.6)), 2))
            ),
            "center",
            0.4,
        ),
        Recipe(single(furniture.armchair), "corner", 0.3),
        Recipe(single(furniture.plant), "corner", 0.6),
        Recipe(single(furniture.lamp), "corner", 0.5),
    ),
}
"""What each kind of room may hold, biggest pieces first (they are placed in this order)."""

ROOM_KINDS: tuple[str, ...] = tuple(RECIPES)
