"""Furniture models built from a few coloured parts, with plausible, randomised sizes.

Every model lives in its own frame: its footprint is the rectangle
``[-width/2, width/2] x [-depth/2, depth/2]`` centred on the origin, it stands on
``z = 0``, and its back (the side that goes against a wall: a sofa's backrest, a
bed's headboard) faces ``+y``. The generator turns and moves it into place.

Sizes follow common furniture dimensions (a dining table is 0.75 m high, a seat
0.45 m, a wardrobe about 2 m); the random draws only vary them within those ranges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ssga_workspace_procedural import textures
from ssga_workspace_procedural.meshes import assemble, blob, block, cylinder, textured_box
from ssga_workspace_procedural.textures import WOODS, Rgb, jitter

FABRICS: tuple[Rgb, ...] = (
    (0.35, 0.4, 0.55),
    (0.55, 0.3, 0.28),
    (0.4, 0.5, 0.35),
    (0.6, 0.58, 0.52),
    (0.25, 0.25, 0.28),
    (0.7, 0.55, 0.3),
)
LACQUERS: tuple[Rgb, ...] = ((0.92, 0.92, 0.9), (0.3, 0.32, 0.35), (0.55, 0.62, 0.6), (0.85, 0.78, 0.65))
METAL: Rgb = (0.3, 0.3, 0.32)


@dataclass(frozen=True, eq=False)
class Model:
    """A piece of furniture in its model frame (see the module docstring)."""

    category: str
    mesh: trimesh.Trimesh
    width: float
    depth: float
    height: float

    @property
    def flat(self) -> bool:
        """A floor covering (a rug): other furniture may stand on it and it blocks nobody's way."""
        return self.height < 0.05


def _choice(rng: np.random.Generator, options: tuple[Rgb, ...], amount: float = 0.04) -> Rgb:
    return jitter(rng, options[int(rng.integers(len(options)))], amount)


def _r(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A size drawn in ``[lo, hi]``, rounded to the centimetre."""
    return round(float(rng.uniform(lo, hi)), 2)


def _legs(w: float, d: float, h: float, size: float, colour: Rgb, inset: float = 0.03) -> list[trimesh.Trimesh]:
    xs, ys = w / 2 - inset - size / 2, d / 2 - inset - size / 2
    return [
        block((sx * xs - size / 2, sy * ys - size / 2, 0), (sx * xs + size / 2, sy * ys + size / 2, h), colour)
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]


def table(rng: np.random.Generator, kind: str = "dining") -> Model:
    """A top on four legs: ``dining``, ``coffee`` (low), ``desk`` or ``nightstand``."""
    w, d, h = {
        "dining": lambda: (_r(rng, 1.2, 1.8), _r(rng, 0.8, 0.95), 0.75),
        "coffee": lambda: (_r(rng, 0.9, 1.2), _r(rng, 0.5, 0.6), 0.42),
        "desk": lambda: (_r(rng, 1.1, 1.5), _r(rng, 0.6, 0.7), 0.75),
        "nightstand": lambda: (_r(rng, 0.4, 0.5), 0.4, _r(rng, 0.5, 0.6)),
    }[kind]()
    wood = _choice(rng, WOODS)
    top = block((-w / 2, -d / 2, h - 0.04), (w / 2, d / 2, h), wood)
    return Model("table", assemble([top, *_legs(w, d, h - 0.04, 0.05, jitter(rng, wood, 0.05))]), w, d, h)


def chair(rng: np.random.Generator) -> Model:
    """A dining chair: seat at 0.45 m on four legs, backrest to about 0.9 m along its back."""
    w, d, seat, h = 0.45, 0.45, 0.45, _r(rng, 0.85, 0.95)
    wood = _choice(rng, WOODS)
    parts = [block((-w / 2, -d / 2, seat - 0.05), (w / 2, d / 2, seat), _choice(rng, FABRICS + WOODS))]
    parts += _legs(w, d, seat - 0.05, 0.04, wood, inset=0.01)
    parts.append(block((-w / 2, d / 2 - 0.05, seat), (w / 2, d / 2, h), wood))
    return Model("chair", assemble(parts), w, d, h)


def sofa(rng: np.random.Generator) -> Model:
    """A base, a backrest along the back, two arms and two or three seat cushions."""
    w, d, h = _r(rng, 1.6, 2.2), _r(rng, 0.85, 0.95), _r(rng, 0.8, 0.9)
    fabric = _choice(rng, FABRICS)
    arm, back = 0.15, 0.2
    parts = [
        block((-w / 2, -d / 2, 0.08), (w / 2, d / 2, 0.4), fabric),
        block((-w / 2, d / 2 - back, 0.4), (w / 2, d / 2, h), fabric),
        block((-w / 2, -d / 2, 0.4), (-w / 2 + arm, d / 2 - back, 0.62), fabric),
        block((w / 2 - arm, -d / 2, 0.4), (w / 2, d / 2 - back, 0.62), fabric),
    ]
    parts += _legs(w, d, 0.08, 0.05, METAL)
    n = 2 if w < 1.9 else 3
    seat_w = (w - 2 * arm) / n
    cushion = jitter(rng, fabric, 0.05)
    for i in range(n):
        x0 = -w / 2 + arm + i * seat_w
        parts.append(block((x0 + 0.01, -d / 2 + 0.02, 0.4), (x0 + seat_w - 0.01, d / 2 - back, 0.5), cushion))
    return Model("sofa", assemble(parts), w, d, h)


def armchair(rng: np.random.Generator) -> Model:
    """A one-seat sofa, labelled ``chair``."""
    w, d, h = _r(rng, 0.75, 0.9), _r(rng, 0.75, 0.85), _r(rng, 0.8, 0.95)
    fabric = _choice(rng, FABRICS)
    parts = [
        block((-w / 2, -d / 2, 0.0), (w / 2, d / 2, 0.42), fabric),
        block((-w / 2, d / 2 - 0.18, 0.42), (w / 2, d / 2, h), fabric),
        block((-w / 2, -d / 2, 0.42), (-w / 2 + 0.14, d / 2 - 0.18, 0.62), fabric),
        block((w / 2 - 0.14, -d / 2, 0.42), (w / 2, d / 2 - 0.18, 0.62), fabric),
    ]
    return Model("chair", assemble(parts), w, d, h)


def bed(rng: np.random.Generator) -> Model:
    """A frame, a mattress, a blanket over its foot end, pillows and a headboard along the back."""
    w = _r(rng, 0.9, 1.0) if rng.random() < 0.3 else _r(rng, 1.4, 1.8)
    d, frame_h = 2.05, 0.3
    wood, linen, blanket = _choice(rng, WOODS), jitter(rng, (0.94, 0.93, 0.9), 0.03), _choice(rng, FABRICS)
    head = 0.06
    parts = [
        block((-w / 2, -d / 2, 0.05), (w / 2, d / 2 - head, frame_h), wood),
        block((-w / 2, d / 2 - head, 0.0), (w / 2, d / 2, _r(rng, 0.9, 1.1)), wood),
        block((-w / 2 + 0.03, -d / 2 + 0.03, frame_h), (w / 2 - 0.03, d / 2 - head, frame_h + 0.2), linen),
        block((-w / 2, -d / 2, frame_h + 0.05), (w / 2, d / 2 - head - 0.6, frame_h + 0.23), blanket),
    ]
    parts += _legs(w, d - head, 0.05, 0.06, wood, inset=0.0)
    n = 1 if w < 1.2 else 2
    for i in range(n):
        x = -w / 2 + (i + 0.5) * w / n
        parts.append(blob((x, d / 2 - head - 0.3, frame_h + 0.27), (0.8 * w / n / 2, 0.18, 0.07), linen))
    return Model("bed", assemble(parts), w, d, float(max(p.bounds[1, 2] for p in parts)))


def cabinet(rng: np.random.Generator, tall: bool) -> Model:
    """A wardrobe (``tall``) or a counter/sideboard: a body with doors and handles on its front."""
    if tall:
        w, d, h = _r(rng, 0.9, 1.6), 0.6, _r(rng, 1.9, 2.1)
    else:
        w, d, h = _r(rng, 1.2, 2.4), 0.6, 0.9
    body = _choice(rng, LACQUERS + WOODS)
    handle, door = -d / 2 + 0.025, -d / 2 + 0.045  # front planes: handles stick out of the doors, the doors out of the body
    parts = [
        block((-w / 2, door, 0.08), (w / 2, d / 2, h), body),
        block((-w / 2 + 0.04, door + 0.04, 0), (w / 2 - 0.04, d / 2, 0.08), METAL),
    ]
    if not tall:
        parts.append(block((-w / 2, -d / 2, h), (w / 2, d / 2, h + 0.03), _choice(rng, WOODS + ((0.2, 0.2, 0.22),))))
    n = max(2, int(w / 0.5))
    door_w = w / n
    front = jitter(rng, body, 0.05)
    for i in range(n):
        x0 = -w / 2 + i * door_w
        parts.append(block((x0 + 0.005, handle, 0.1), (x0 + door_w - 0.005, door, h - 0.02), front))
        hx = x0 + (door_w - 0.06 if i % 2 == 0 else 0.06)
        hz = h - 0.25 if not tall else 1.0
        parts.append(block((hx - 0.01, -d / 2, hz - 0.08), (hx + 0.01, handle, hz + 0.08), METAL))
    return Model("cabinet", assemble(parts), w, d, float(h + (0 if tall else 0.03)))


def shelf(rng: np.random.Generator) -> Model:
    """A bookcase: sides, back, boards, and rows of books of random colours and sizes."""
    w, d, h = _r(rng, 0.8, 1.2), 0.35, _r(rng, 1.6, 2.0)
    wood = _choice(rng, WOODS + LACQUERS)
    t = 0.025
    boards = int(rng.integers(4, 6))
    parts = [
        block((-w / 2, -d / 2, 0), (-w / 2 + t, d / 2, h), wood),
        block((w / 2 - t, -d / 2, 0), (w / 2, d / 2, h), wood),
        block((-w / 2 + t, d / 2 - 0.01, 0), (w / 2 - t, d / 2, h), jitter(rng, wood, 0.08)),
    ]
    levels = np.linspace(0.05, h - t, boards + 1)
    for i, z in enumerate(levels):
        parts.append(block((-w / 2 + t, -d / 2, z - t), (w / 2 - t, d / 2 - 0.01, z), wood))
        if i == len(levels) - 1:
            break
        gap = levels[i + 1] - t - z
        x = -w / 2 + t + 0.02
        while x < w / 2 - t - 0.15 and rng.random() < 0.93:
            bw = _r(rng, 0.02, 0.06)
            bh = min(gap - 0.02, _r(rng, 0.6, 0.95) * gap)
            book = jitter(rng, (0.5, 0.4, 0.35), 0.35)
            parts.append(block((x, -d / 2 + 0.04, z), (x + bw, d / 2 - 0.03, z + bh), book))
            x += bw + (0.003 if rng.random() < 0.85 else _r(rng, 0.05, 0.15))
    return Model("shelf", assemble(parts), w, d, h)


def plant(rng: np.random.Generator) -> Model:
    """A pot, a stem and two or three clumps of foliage."""
    r = _r(rng, 0.14, 0.22)
    pot_h = _r(rng, 0.25, 0.4)
    h = _r(rng, 0.7, 1.6)
    leaf = jitter(rng, (0.2, 0.45, 0.18), 0.08)
    pot = _choice(rng, ((0.65, 0.35, 0.22), (0.9, 0.9, 0.88), (0.2, 0.2, 0.22)))
    spread = min(0.38, r + 0.15)
    parts = [cylinder(0, 0, 0, pot_h, r * 0.8, pot, top_radius=r), cylinder(0, 0, pot_h, h - spread, 0.015, (0.35, 0.25, 0.15))]
    n = int(rng.integers(2, 4))
    for i in range(n):
        a = 2 * np.pi * i / n + rng.uniform(0, 1)
        cx, cy = 0.35 * spread * np.cos(a), 0.35 * spread * np.sin(a)
        z = h - spread + rng.uniform(-0.1, 0.05) * h
        rad = 0.65 * spread
        parts.append(
            blob((cx, cy, min(z, h - rad)), (rad, rad, rad * _r(rng, 0.9, 1.3)), jitter(rng, leaf, 0.05), subdivisions=2)
        )
    mesh = assemble(parts)
    lo, hi = mesh.bounds
    side = float(2 * max(np.abs(lo[:2]).max(), np.abs(hi[:2]).max()))
    return Model("plant", mesh, side, side, float(hi[2]))


def lamp(rng: np.random.Generator) -> Model:
    """A floor lamp: base, pole and shade."""
    h = _r(rng, 1.5, 1.75)
    shade_r = _r(rng, 0.14, 0.2)
    shade = _choice(rng, ((0.95, 0.9, 0.78), (0.85, 0.85, 0.82), (0.7, 0.55, 0.4)), 0.03)
    parts = [
        cylinder(0, 0, 0, 0.03, 0.14, METAL),
        cylinder(0, 0, 0.03, h - 0.3, 0.015, METAL),
        cylinder(0, 0, h - 0.32, h, shade_r, shade, top_radius=shade_r * 0.7),
    ]
    side = 2 * max(0.14, shade_r)
    return Model("lamp", assemble(parts), side, side, h)


def rug(rng: np.random.Generator, width: float, depth: float) -> Model:
    """A 1 cm thick rug with a woven pattern stretched over its top."""
    colour, accent = _choice(rng, FABRICS, 0.08), _choice(rng, FABRICS + LACQUERS, 0.08)
    mesh = textured_box((-width / 2, -depth / 2, 0.0), (width / 2, depth / 2, 0.01), textures.rug(rng, colour, accent), fit="+z")
    return Model("rug", mesh, width, depth, 0.01)
