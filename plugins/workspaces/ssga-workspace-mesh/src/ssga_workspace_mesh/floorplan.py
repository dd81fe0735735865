"""Floor plans of mesh scenes: read from a JSON file, or derived from the mesh itself.

A derived plan needs no labels, only two assumptions that hold for scans and for
generated houses alike: the floor is at ``z = 0`` (ssga's convention) and surfaces
face outwards (normals point out of solid walls and furniture, into the rooms). The
second one is what tells "inside a thick wall" from "inside a room": from inside a
solid, a horizontal ray sees the back of a surface.

A scan that ends below the camera (no ceiling, walls scanned to 1.4 m as ScanNet's are)
has nothing at camera height to enclose its floor: :func:`floor_plan_for_scan` then
derives the plan lower, inside the scan, and says so; where no height works, the error
names which condition no point met (:class:`NoFreeFloor`).

The JSON format is the core's (:meth:`ssga_bench.workspace.FloorPlan.to_json`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import shapely
import trimesh
from shapely.geometry.base import BaseGeometry

from ssga_core import InputError
from ssga_bench import read_json
from ssga_bench import FloorPlan, grid_polygons
from ssga_workspace_mesh.meshdata import FlatMesh, RayCaster, flatten_scene

PROBE_DIRECTIONS = 16
"""Horizontal rays cast from each probe point."""

ENCLOSED_FRACTION = 0.75
"""A point is inside the building if this share of its horizontal rays hit something:
an open door or window lets a few escape, standing outside lets about half escape."""

_BATCH = 1 << 15  # probe points per Embree call, to bound memory on large scenes


WALL_BAND = (0.3, 1.0)
"""Heights, metres, at which every room scan has its walls: the reference for :func:`wall_top`."""

WALL_SHARE = 0.5
"""The walls end where less than this share of the vertical area per metre of height of
:data:`WALL_BAND` is left."""

LOWERED_SHARE = 0.8
"""Where the configured camera height meets no geometry, views are taken at this share of
the walls' top (:func:`floor_plan_for_scan`)."""


class NoFreeFloor(InputError):
    """:func:`floor_plan_from_mesh` found nowhere to stand.

    Attributes:
        cause: ``"floor"`` (no horizontal surface at ``z = 0``), ``"height"`` (floor, but
            nothing at camera height around it: the mesh ends below the camera),
            ``"solid"`` (every such point is inside a solid) or ``"clearance"`` (none is
            far enough from the occluders).
        reason: the message without the mesh's name.
        wall_top: height the mesh's walls reach (:func:`wall_top`), None if it has none.
    """

    def __init__(self, source: str, cause: str, reason: str, wall_top: float | None) -> None:
        super().__init__(f"{source}: found no free floor: {reason}")
        self.source, self.cause, self.reason, self.wall_top = source, cause, reason, wall_top

    def __reduce__(self) -> tuple[type, tuple[str, str, str, float | None]]:
        # Raised in worker processes too: rebuilt from its fields, not from its message.
        return type(self), (self.source, self.cause, self.reason, self.wall_top)


def floor_plan_from_mesh(
    scene: trimesh.Scene | trimesh.Trimesh,
    camera_height: float = 1.5,
    clearance: float = 0.25,
    *,
    resolution: float = 0.1,
    floor_tolerance: float = 0.3,
    wall_width: float = 0.05,
    source: str = "mesh",
) -> FloorPlan:
    """Derive where a camera may stand, and what blocks sight, from a mesh.

    Args:
        scene: the scene in ssga's world frame (z up, metres, floor at ``z = 0``).
        camera_height: height of the camera above the floor; the occluders are the
            mesh's cross-section there.
        clearance: how far a camera must stay from any occluder.
        resolution: spacing of the grid of candidate standing points, metres.
        floor_tolerance: how far from ``z = 0`` a horizontal surface still counts as floor.
        wall_width: width given to zero-thickness surfaces (single quads) in the
            cross-section, so they become polygons.
        source: what to call the mesh in error messages (its file).

    Returns:
        ``occluders``: the cross-section at ``camera_height``, solids filled;
        ``free``: grid cells with floor below, a roof above or walls around, outside
        any solid, farther than ``clearance`` from every occluder.

    Raises:
        NoFreeFloor: no point of the mesh qualifies as free floor; the message says which
            condition none met (an :class:`InputError`).
    """
    flat = flatten_scene(scene)
    caster = RayCaster(flat.vertices, flat.faces)
    probe = _Probe(caster, flat.normals, camera_height)
    occluders = _cross_section(flat.vertices, flat.faces, probe, camera_height, wall_width)
    standable, met = _standable_area(flat.vertices, probe, resolution, floor_tolerance)
    free = _polygonal(standable.difference(occluders.buffer(clearance)), min_area=resolution**2)
    if free.is_empty:
        top = wall_top(flat)
        if not met["floor"]:
            cause, reason = "floor", f"no horizontal surface at z = 0 +- {floor_tolerance} m; is the floor at z = 0 and up_axis right?"
        elif not met["outside"]:
            cause, reason = "solid", (
                f"every floor point is inside a solid at camera height {camera_height:g} m (surfaces should face out of "
                "solids, into rooms)"
            )
        elif not met["enclosed"]:
            walls = f"the mesh's walls end at about {top:.2f} m; set camera_height below that" if top is not None else "the mesh has no walls"
            cause, reason = "height", (
                f"no geometry at camera height {camera_height:g} m around the floor (no roof above it, and fewer than "
                f"{ENCLOSED_FRACTION:.0%} of horizontal rays there hit anything): {walls}"
            )
        else:
            cause, reason = "clearance", f"no floor farther than {clearance:g} m from anything at camera height {camera_height:g} m"
        raise NoFreeFloor(source, cause, reason, top)
    return FloorPlan(free=free, occluders=occluders)


def floor_plan_for_scan(
    scene: trimesh.Scene | trimesh.Trimesh, camera_height: float, *, source: str = "mesh"
) -> tuple[FloorPlan, float, str | None]:
    """:func:`floor_plan_from_mesh` at ``camera_height``, or lower where the mesh ends below it.

    A scan without its ceiling ends where the scanner stopped (ScanNet's near 1.4 m, below
    the default camera's 1.5 m), so nothing encloses the floor at the camera's height.
    Then the plan is derived again at :data:`LOWERED_SHARE` of the walls' top (:func:`wall_top`),
    and the views are to be taken there. Where the configured height works, the plan is
    exactly :func:`floor_plan_from_mesh`'s.

    Returns:
        The plan, the camera height it was derived at, and a line saying why that is not
        the configured one (None when it is).

    Raises:
        NoFreeFloor: no free floor at either height; the message names both.
    """
    try:
        return floor_plan_from_mesh(scene, camera_height, source=source), camera_height, None
    except NoFreeFloor as exc:
        if exc.cause != "height" or exc.wall_top is None or round(LOWERED_SHARE * exc.wall_top, 2) >= camera_height:
            raise
        top, lower = exc.wall_top, round(LOWERED_SHARE * exc.wall_top, 2)
    try:
        plan = floor_plan_from_mesh(scene, lower, source=source)
    except NoFreeFloor as again:
        raise NoFreeFloor(
            source, again.cause, f"none at camera height {camera_height:g} m (the mesh's walls end at about {top:.2f} m), "
            f"nor at {lower:g} m: {again.reason}", again.wall_top
        ) from None
    note = (
        f"{source}: no geometry at camera_height {camera_height:g} m (the scan's walls end at about {top:.2f} m); "
        f"views are taken at {lower:g} m, {LOWERED_SHARE:g} x the walls' top (set camera_height to choose)"
    )
    return plan, lower, note


def wall_top(flat: FlatMesh, bin_size: float = 0.02) -> float | None:
    """Height at which the walls of a mesh (floor at ``z = 0``) end; None if it has none above the floor.

    Near-vertical surface area per metre of height, each face spread evenly over the
    heights it spans, is measured in ``bin_size`` bins (smoothed over 10 cm); the walls
    end at the first height above :data:`WALL_BAND` where it falls below :data:`WALL_SHARE`
    of its median in that band. A room with a ceiling gives its ceiling's height, a scan
    that stopped at 1.4 m about 1.4 m, whatever furniture stands higher.
    """
    triangles = flat.vertices[flat.faces]
    vertical = np.abs(flat.normals[:, 2]) < 0.3
    low, high = np.clip(triangles[vertical, :, 2].min(axis=1), 0.0, None), triangles[vertical, :, 2].max(axis=1)
    keep = high - low > 1e-6
    if not keep.any():
        return None
    tri = triangles[vertical][keep].astype(np.float64)
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1) / 2.0
    low, high = low[keep], high[keep]
    bins = min(math.ceil(float(high.max()) / bin_size) + 1, 100_000)
    rate = area / (high - low)
    start = np.minimum((low / bin_size).astype(np.int64), bins - 1)
    stop = np.minimum((high / bin_size).astype(np.int64), bins - 1)
    per_metre = np.cumsum(np.bincount(start, rate, bins) - np.bincount(stop, rate, bins))
    per_metre = np.convolve(per_metre, np.ones(5) / 5.0, mode="same")
    centres = (np.arange(bins) + 0.5) * bin_size
    band = (centres >= WALL_BAND[0]) & (centres <= WALL_BAND[1])
    if not band.any() or np.median(per_metre[band]) <= 0:
        return float(high.max())
    above = centres > WALL_BAND[0]
    below = np.flatnonzero(above & (per_metre < WALL_SHARE * float(np.median(per_metre[band]))))
    return float(centres[below[0]]) if len(below) else float(high.max())


class _Probe:
    """Ray probes at camera height that classify points of the floor plane."""

    def __init__(self, caster: RayCaster, normals: np.ndarray, height: float) -> None:
        self.caster, self.normals, self.height = caster, normals, height
        # Offset from the axes, so no probe grazes an axis-aligned wall.
        angles = np.arange(PROBE_DIRECTIONS) * (2.0 * math.pi / PROBE_DIRECTIONS) + 0.1
        self.directions = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=-1).astype(np.float32)

    def _origins(self, xy: np.ndarray, repeat: int = 1) -> np.ndarray:
        origins = np.empty((len(xy), 3), dtype=np.float32)
        origins[:, :2], origins[:, 2] = xy, self.height
        return np.repeat(origins, repeat, axis=0)

    def horizontal(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each point: the share of horizontal rays that hit, and the share that hit a surface's back."""
        k = len(self.directions)
        directions = np.tile(self.directions, (len(xy), 1))
        face, _, _ = self.caster.first_hit(self._origins(xy, k), directions)
        hit = face >= 0
        back = np.zeros_like(hit)
        back[hit] = np.einsum("ij,ij->i", self.normals[face[hit]], directions[hit]) > 0
        return hit.reshape(-1, k).mean(axis=1), back.reshape(-1, k).mean(axis=1)

    def vertical(self, xy: np.ndarray, down: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each point, a ray straight down or up: hit?, hit height, |normal z| of the surface hit."""
        direction = np.array([0.0, 0.0, -1.0 if down else 1.0], dtype=np.float32)
        face, t, _ = self.caster.first_hit(self._origins(xy), np.broadcast_to(direction, (len(xy), 3)))
        hit = face >= 0
        z = np.where(hit, self.height + direction[2] * t, np.nan)
        flat = np.where(hit, np.abs(self.normals[np.maximum(face, 0), 2]), 0.0)
        return hit, z, flat

    def inside_solid(self, xy: np.ndarray) -> np.ndarray:
        _, back = self.horizontal(xy)
        return back > 0.5


def _cross_section(vertices: np.ndarray, faces: np.ndarray, probe: _Probe, height: float, wall_width: float) -> BaseGeometry:
    """The mesh cut at ``height``: every cut segment widened by ``wall_width``, solids filled."""
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    segments = trimesh.intersections.mesh_plane(mesh, plane_normal=[0.0, 0.0, 1.0], plane_origin=[0.0, 0.0, height])
    if len(segments) == 0:
        return shapely.Polygon()
    segments = np.round(np.asarray(segments)[:, :, :2], 5)  # snap shared endpoints so the cut closes into rings
    segments = segments[np.any(segments[:, 0] != segments[:, 1], axis=1)]
    lines = shapely.multilinestrings(shapely.linestrings(segments))
    outline = lines.buffer(wall_width / 2.0, cap_style="square", join_style="mitre")
    faces_2d = list(shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.node(lines)))))
    if not faces_2d:
        return outline
    points = shapely.get_coordinates(shapely.point_on_surface(faces_2d))
    solid = [f for f, inside in zip(faces_2d, _batched(probe.inside_solid, points), strict=True) if inside]
    return _polygonal(shapely.union_all([outline, *solid]))


def _standable_area(
    vertices: np.ndarray, probe: _Probe, resolution: float, floor_tolerance: float
) -> tuple[BaseGeometry, dict[str, bool]]:
    """Grid cells (as polygons) whose centre has floor below and a roof above or walls around, outside
    any solid; and whether any centre met the conditions in turn (``floor``, ``outside`` a solid, ``enclosed``)."""
    lo, hi = vertices[:, :2].min(axis=0), vertices[:, :2].max(axis=0)
    xs = np.arange(lo[0] + resolution / 2.0, hi[0], resolution)
    ys = np.arange(lo[1] + resolution / 2.0, hi[1], resolution)
    if len(xs) == 0 or len(ys) == 0:
        return shapely.Polygon(), {"floor": False, "outside": False, "enclosed": False}
    gx, gy = np.meshgrid(xs, ys)
    xy = np.stack([gx.ravel(), gy.ravel()], axis=-1).astype(np.float32)

    def classify(points: np.ndarray) -> np.ndarray:
        down, floor_z, level = probe.vertical(points, down=True)
        floor = down & (np.abs(floor_z) <= floor_tolerance) & (level > 0.9)
        up, _, _ = probe.vertical(points, down=False)
        hits, back = probe.horizontal(points)
        outside = floor & (back <= 0.5)
        return np.stack([floor, outside, outside & (up | (hits >= ENCLOSED_FRACTION))], axis=-1)

    conditions = _batched(classify, xy)
    met = dict(zip(("floor", "outside", "enclosed"), (bool(c) for c in conditions.any(axis=0)), strict=True))
    mask = conditions[:, 2].reshape(gy.shape)
    return grid_polygons(mask, (xs[0] - resolution / 2.0, ys[0] - resolution / 2.0), resolution), met


def _batched(fn: Callable[[np.ndarray], np.ndarray], points: np.ndarray) -> np.ndarray:
    """``fn`` over ``points`` in batches (a grid over a whole house is millions of rays)."""
    return np.concatenate([fn(points[i : i + _BATCH]) for i in range(0, max(len(points), 1), _BATCH)])


def _polygonal(geom: BaseGeometry, min_area: float = 0.0) -> BaseGeometry:
    """Only the polygons of ``geom`` with at least ``min_area``, as one (Multi)Polygon."""
    parts = [p for p in shapely.get_parts(geom) if p.geom_type == "Polygon" and p.area >= min_area and not p.is_empty]
    parts += [q for p in shapely.get_parts(geom) if p.geom_type == "MultiPolygon" for q in p.geoms if q.area >= min_area]
    if not parts:
        return shapely.Polygon()
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def load_floor_plan(path: str | Path) -> FloorPlan:
    """Read a floor plan in the core's JSON format (:meth:`ssga_bench.workspace.FloorPlan.to_json`).

    Raises:
        InputError: the file is missing, not JSON, or not lists of polygons; one line naming the file.
    """
    return FloorPlan.from_json(read_json(path), str(path))
