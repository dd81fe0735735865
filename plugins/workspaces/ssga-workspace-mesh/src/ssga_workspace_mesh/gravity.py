"""Which way is up in a scan: gravity from the mesh's dominant horizontal planes.

A scan comes in whatever frame its device started in (a phone's ``y`` axis points where
the phone did), so ``up_axis = "auto"`` finds up from the surfaces themselves, and an
explicit up vector (the floor's normal in the file's frame) levels a mesh whose up is
known. Either way the mesh is turned by the smallest rotation that takes up to ``+z``
(a mesh already ``z`` up is not turned about the vertical), then moved along ``z`` so
that its floor is at ``z = 0``, as ssga's world wants (:mod:`ssga_core.geometry`).

The rule, in three steps (:func:`find_up`, :func:`floor_height`):

1. **The vertical axis** is the direction along which the most surface area faces:
   face normals weighted by area, each counted for every direction of a grid over the
   half sphere within :data:`AXIS_CONE_DEG` of it, the more the nearer (a normal and
   its opposite lie on one axis), the best direction refined to the area-weighted
   principal axis of the normals near it. In a room the floor and the ceiling
   together, with every tabletop, seat and shelf, outweigh any one pair of opposite
   walls (a 3.5 x 4.4 m office 2.5 m high: 31 m^2 of floor and ceiling against 22 m^2
   of the longer walls).
   When another of the three dominant directions (each at least 45 degrees from the
   others) has :data:`CLOSE_CALL` of that area or more (a room scanned without its
   ceiling, whose long walls rival its floor), the one along which the mesh is
   thinnest wins: rooms are wider than they are high.
2. **Its sign**: furniture stands on the floor, so the mesh's area lies mostly in
   the lower half of its height; a scan without its ceiling leans the same way. Up
   is the direction in which the area-weighted mean height of all faces is below the
   middle of the mesh's span.
3. **The floor** is the lowest level (2 cm bins: :func:`ssga_bench.lowest_level`) with at least
   :data:`FLOOR_SHARE` of the upward-facing area of the busiest level, which passes
   over scanning debris below the floor and over tabletops above it.

Where it fails: a corridor, or a room higher than it is wide, whose walls outweigh its
floor and ceiling; an empty shell whose floor and ceiling mirror each other (the sign
is then a guess); a mesh that is mostly terrain. The line it prints says what it found;
give ``up_axis`` as a vector there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import trimesh

from ssga_core import InputError
from ssga_bench import lowest_level, rotation_to_z, weighted_quantiles
from ssga_workspace_mesh.meshdata import flatten_scene

UpAxis = Literal["y", "z", "auto"] | tuple[float, float, float]
"""A mesh file's up: ``"y"`` (glTF, Habitat), ``"z"`` (ssga's own frame), ``"auto"`` (found
from the mesh), or a vector in the file's frame."""

AXIS_CONE_DEG = 10.0
"""Normals within this angle of a direction count for it (scans' floors are not flat to a degree)."""

FLOOR_SHARE = 0.5
"""The floor is the lowest level with at least this share of the busiest level's upward area."""

CLOSE_CALL = 0.6
"""Axes with at least this share of the best one's area are a close call, which the
thinnest of them wins; the line printed warns when that was not the one with most area."""

_DIRECTIONS = 4000
"""Directions over the half sphere tried for the vertical axis (about 2 degrees apart)."""


@dataclass(frozen=True)
class Levelling:
    """What levelling a mesh found and did."""

    up: np.ndarray
    """Unit up vector in the file's frame."""
    found: bool
    """True if ``up`` was found from the mesh, False if it was given."""
    share: float
    """Share of the mesh's area that faces along the up axis (floors, ceilings, tabletops)."""
    floor: float
    """Height of the floor after the turn, before the shift that puts it at ``z = 0``."""
    transform: np.ndarray
    """The ``4 x 4`` transform applied: the turn, then the shift."""
    passed_over: float = 0.0
    """Share of the area facing along an axis with more of it than ``up``'s, passed over
    because the mesh is thinner along ``up`` (0 if none was)."""

    @property
    def turn_deg(self) -> float:
        """Angle of the turn that took ``up`` to ``+z``."""
        return math.degrees(math.acos(float(np.clip(self.up[2], -1.0, 1.0))))

    def nearest_axis(self) -> tuple[str, float]:
        """The file's axis nearest to ``up`` (``"-y"``) and the angle between them: the tilt corrected."""
        k = int(np.argmax(np.abs(self.up)))
        sign = "-" if self.up[k] < 0 else "+"
        return f"{sign}{'xyz'[k]}", math.degrees(math.acos(float(np.clip(abs(self.up[k]), 0.0, 1.0))))

    def describe(self) -> str:
        axis, tilt = self.nearest_axis()
        x, y, z = (float(v) for v in self.up)
        how = f"found up ({x:.3f}, {y:.3f}, {z:.3f})" if self.found else f"up given as ({x:.3f}, {y:.3f}, {z:.3f})"
        line = (
            f"{how} in the file's frame, {tilt:.1f} deg from its {axis} axis, {100 * self.share:.0f}% of the surface facing "
            f"along it; turned {self.turn_deg:.1f} deg to z up and the floor (found at z = {self.floor:.3f}) moved to z = 0"
        )
        if self.passed_over:
            line += (
                f" (the mesh is thinnest along it; another axis has {100 * self.passed_over:.0f}% of the surface facing along "
                "it: if the views are not level, give up_axis as the floor's normal)"
            )
        return line


def parse_up_axis(value: object, source: str = "up_axis") -> UpAxis:
    """``value`` as an :data:`UpAxis`, or an :class:`InputError` naming ``source``."""
    if isinstance(value, str) and value in ("y", "z", "auto"):
        return value  # type: ignore[return-value]
    try:
        vector = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        vector = np.empty(0)
    if vector.shape != (3,) or not np.isfinite(vector).all() or np.linalg.norm(vector) < 1e-9:
        raise InputError(f"{source}: up_axis must be 'y', 'z', 'auto' or a non-zero [x, y, z] vector, got {value!r}")
    return (float(vector[0]), float(vector[1]), float(vector[2]))


def level_scene(scene: trimesh.Scene, up_axis: Literal["auto"] | Sequence[float]) -> Levelling:
    """Turn ``scene`` so that its up (found, or the vector given) is ``+z``, its floor at ``z = 0``.

    Raises:
        InputError: the mesh has no surface to find up or the floor from.
    """
    flat = flatten_scene(scene)
    triangles = flat.vertices.astype(np.float64)[flat.faces]
    normals = flat.normals.astype(np.float64)  # mirrored instances already turned back
    areas = np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1) / 2.0
    if areas.sum() <= 0:
        raise InputError("no surface with an area to find up from")
    passed_over = 0.0
    if isinstance(up_axis, str):
        up, passed_over = find_up(triangles, normals, areas)
        found = True
    else:
        up = np.asarray(up_axis, dtype=np.float64)
        up, found = up / np.linalg.norm(up), False
    turn = np.eye(4)
    turn[:3, :3] = rotation_to_z(up)
    turned = triangles @ turn[:3, :3].T
    floor = floor_height(turned, normals @ turn[:3, :3].T, areas)
    transform = trimesh.transformations.translation_matrix((0.0, 0.0, -floor)) @ turn
    scene.apply_transform(transform)
    return Levelling(up=up, found=found, share=_share(normals, areas, up), floor=floor, transform=transform, passed_over=passed_over)


def find_up(triangles: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> tuple[np.ndarray, float]:
    """The unit up vector of a mesh given as ``(F, 3, 3)`` triangles with their unit normals
    and areas (steps 1 and 2), and the share of area along the axis it passed over for a
    thinner one (0 if it did not)."""
    centres = triangles.mean(axis=1)
    axes = _dominant_axes(normals, areas)
    shares = [_share(normals, areas, axis) for axis in axes]
    # Close calls go to the thinnest axis: rooms are wider than they are high.
    close = [k for k, share in enumerate(shares) if share >= CLOSE_CALL * shares[0]]
    extents = {k: _extent(centres @ axes[k], areas) for k in close}
    chosen = min(close, key=lambda k: extents[k][1] - extents[k][0])
    up = axes[chosen]
    low, high = extents[chosen]
    if float(np.average(centres @ up, weights=areas)) > (low + high) / 2.0:
        up = -up
    return up, (shares[0] if chosen else 0.0)


def floor_height(triangles: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> float:
    """Height of the floor of a mesh already ``z`` up (step 3). Upward-facing means the
    normal points up: surfaces face out of solids, into rooms, as exporters and scanners
    write them (the floor plan assumes it too)."""
    cos = math.cos(math.radians(AXIS_CONE_DEG))
    upward = normals[:, 2] >= cos
    if not upward.any():
        raise InputError("no upward-facing surface to take for the floor (surfaces should face out of solids, into rooms)")
    z, weight = triangles[upward].mean(axis=1)[:, 2], areas[upward]
    return lowest_level(z, weight, FLOOR_SHARE)


def _dominant_axes(normals: np.ndarray, areas: np.ndarray) -> list[np.ndarray]:
    """Up to three directions (signs arbitrary), each at least 45 degrees from the others, with
    the most area facing along them, most first, refined: a room's floor and its walls' two axes."""
    # Fold each normal onto the upper half sphere, and merge normals 1/64 apart, so a
    # scan of a million faces costs what a few thousand distinct directions do.
    folded = np.where(normals[:, 2:3] < 0, -normals, normals)
    cells = np.rint(folded * 64).astype(np.int64) + 64  # 0..128 per coordinate
    codes, inverse = np.unique((cells[:, 0] * 129 + cells[:, 1]) * 129 + cells[:, 2], return_inverse=True)
    weight = np.bincount(inverse, weights=areas, minlength=len(codes))
    keys = np.stack([codes // (129 * 129), codes // 129 % 129, codes % 129], axis=-1) - 64.0
    directions = keys / np.maximum(np.linalg.norm(keys, axis=1, keepdims=True), 1e-12)
    cos = math.cos(math.radians(AXIS_CONE_DEG))
    grid = _half_sphere(_DIRECTIONS)
    # A kernel that falls to zero at the cone's edge, so the best direction is a cluster's
    # centre, not the first of the many that hold all of it.
    scores = np.concatenate([np.clip(np.abs(chunk @ directions.T) - cos, 0.0, None) @ weight for chunk in np.array_split(grid, 8)])
    axes: list[np.ndarray] = []
    allowed = np.ones(len(grid), dtype=bool)
    while len(axes) < 3 and allowed.any() and scores[allowed].max() > 0:
        best = grid[allowed][int(np.argmax(scores[allowed]))]
        axes.append(_refined(best, normals, areas))
        allowed &= np.abs(grid @ best) <= math.cos(math.radians(45.0))
    return axes


def _refined(axis: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """``axis`` moved to the area-weighted principal axis of the normals near it, twice, the
    second time in a narrower cone (a scan's floor to a tenth of a degree)."""
    for cone in (AXIS_CONE_DEG, AXIS_CONE_DEG / 2):
        near = np.abs(normals @ axis) >= math.cos(math.radians(cone))
        if not near.any():
            break
        n, w = normals[near], areas[near]
        _, vectors = np.linalg.eigh((n * w[:, None]).T @ n)
        axis = vectors[:, -1]
    return axis / np.linalg.norm(axis)


def _share(normals: np.ndarray, areas: np.ndarray, axis: np.ndarray) -> float:
    """Share of the area whose normals lie within :data:`AXIS_CONE_DEG` of ``axis`` (either way)."""
    return float(areas[np.abs(normals @ axis) >= math.cos(math.radians(AXIS_CONE_DEG))].sum() / areas.sum())


def _half_sphere(count: int) -> np.ndarray:
    """``(count, 3)`` unit vectors spread evenly over the half sphere ``z >= 0`` (a Fibonacci lattice)."""
    k = np.arange(count) + 0.5
    z = 1.0 - k / count
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def _extent(heights: np.ndarray, areas: np.ndarray) -> tuple[float, float]:
    """How far the mesh extends along an axis, the outermost 0.5% of its area left out either side."""
    low, high = weighted_quantiles(heights, areas, (0.005, 0.995))
    return low, high
