"""Small synthetic scenes with known geometry, for tests, benchmarks and examples.

They are built in ssga's world frame (z up, metres, floor top at ``z = 0``) and carry
their ids in ``metadata["semantic_id"]`` / ``["instance_id"]``, as the renderer reads.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh
from PIL import Image
from trimesh.visual.material import PBRMaterial

from ssga_workspace_mesh.meshdata import FACE_INSTANCE, FACE_SEMANTIC

WALL, FLOOR, CEILING, CRATE = 1, 2, 3, 4
"""Semantic ids of :func:`box_room`."""

CRATES = {"crate_a": ((2.0, 1.5), (0.6, 0.6, 1.8)), "crate_b": ((-2.0, -1.5), (0.8, 0.5, 2.2))}
"""Crate name -> ((x, y) centre, (dx, dy, dz) size); both stand on the floor and cross camera height."""


def solid_box(
    extents: tuple[float, float, float], center: tuple[float, float, float], rgba: tuple[int, ...]
) -> trimesh.Trimesh:
    """An axis-aligned box with outward normals and one flat colour."""
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(center)
    box.visual.face_colors = rgba
    return box


def box_room(
    size: tuple[float, float] = (8.0, 6.0), height: float = 3.0, thickness: float = 0.1, crates: bool = True
) -> trimesh.Scene:
    """A closed rectangular room centred on the origin, walls of different colours, and two crates.

    The walls' inner faces are at ``x = +-size[0]/2`` and ``y = +-size[1]/2``; the floor's
    top at ``z = 0``, the ceiling's underside at ``z = height``. Instance ids are 10, 11...
    in the order of the geometries.
    """
    sx, sy = size
    t = thickness
    parts: dict[str, tuple[trimesh.Trimesh, int]] = {
        "wall_east": (solid_box((t, sy + 2 * t, height), (sx / 2 + t / 2, 0, height / 2), (200, 40, 40, 255)), WALL),
        "wall_west": (solid_box((t, sy + 2 * t, height), (-sx / 2 - t / 2, 0, height / 2), (40, 40, 200, 255)), WALL),
        "wall_north": (solid_box((sx, t, height), (0, sy / 2 + t / 2, height / 2), (40, 180, 40, 255)), WALL),
        "wall_south": (solid_box((sx, t, height), (0, -sy / 2 - t / 2, height / 2), (210, 200, 40, 255)), WALL),
        "floor": (solid_box((sx + 2 * t, sy + 2 * t, t), (0, 0, -t / 2), (120, 120, 120, 255)), FLOOR),
        "ceiling": (solid_box((sx + 2 * t, sy + 2 * t, t), (0, 0, height + t / 2), (235, 235, 235, 255)), CEILING),
    }
    if crates:
        for name, ((x, y), (dx, dy, dz)) in CRATES.items():
            parts[name] = (solid_box((dx, dy, dz), (x, y, dz / 2), (230, 140, 30, 255)), CRATE)
    scene = trimesh.Scene()
    for index, (name, (mesh, semantic)) in enumerate(parts.items()):
        mesh.metadata.update(semantic_id=semantic, instance_id=10 + index)
        scene.add_geometry(mesh, geom_name=name)
    return scene


def textured_quad(corners: np.ndarray, image: np.ndarray) -> trimesh.Trimesh:
    """A quad through four corners (top-left, top-right, bottom-right, bottom-left, as seen from its front)
    showing ``image`` upright and unmirrored from the front."""
    corners = np.asarray(corners, dtype=np.float64)
    # trimesh's uv: origin at the image's bottom-left, v up.
    uv = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    # Counter-clockwise seen from the front, so the normal faces the viewer.
    quad = trimesh.Trimesh(vertices=corners, faces=[[0, 3, 2], [0, 2, 1]], process=False)
    quad.visual = trimesh.visual.TextureVisuals(uv=uv, material=PBRMaterial(baseColorTexture=Image.fromarray(image)))
    return quad


def textured_clutter(triangles: int = 50_000, seed: int = 0, room: float = 12.0) -> trimesh.Scene:
    """A textured room full of textured boxes, about ``triangles`` triangles in all: a benchmark scene.

    Every box (the room's shell included) is subdivided three times (768 triangles), so
    the triangle count sets the number of boxes; each box has its own random texture.
    """
    rng = np.random.default_rng(seed)
    shell = trimesh.creation.box(extents=(room, room, 3.0))
    shell.apply_translation((0, 0, 1.5))
    shell.invert()  # normals into the room
    boxes = [shell]
    for _ in range(max(0, round(triangles / 768) - 1)):
        size = rng.uniform(0.3, 1.5, 3)
        x, y = rng.uniform(-room / 2.5, room / 2.5, 2)
        boxes.append(trimesh.creation.box(extents=size).apply_translation((x, y, size[2] / 2)))
    scene = trimesh.Scene()
    for index, box in enumerate(boxes):
        box = box.subdivide().subdivide().subdivide()
        texture = rng.integers(0, 256, (128, 128, 3), dtype=np.uint8)
        box.visual = trimesh.visual.TextureVisuals(
            uv=_planar_uv(box.vertices), material=PBRMaterial(baseColorTexture=Image.fromarray(texture))
        )
        box.metadata.update(semantic_id=index % 5, instance_id=index)
        scene.add_geometry(box, geom_name=f"box_{index}")
    return scene


def subdivided(scene: trimesh.Scene, min_triangles: int) -> trimesh.Scene:
    """``scene`` with every triangle split in four, as often as it takes to reach ``min_triangles``.

    Texture coordinates and vertex colours are interpolated and face colours and per-face
    ids repeated, so the scene renders as before: a stand-in for a scan's dense mesh (HM3D's
    are 0.5-1 million triangles) built from a scene with the same look and fewer triangles.
    """
    total = sum(len(g.faces) for g in scene.geometry.values() if isinstance(g, trimesh.Trimesh))
    times = max(0, math.ceil(math.log(min_triangles / max(total, 1), 4)))
    out = trimesh.Scene()
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geometry = scene.geometry[name]
        if isinstance(geometry, trimesh.Trimesh) and times:
            geometry = _subdivide(geometry, times)
        out.add_geometry(geometry, geom_name=name, node_name=node, transform=transform)
    return out


def _subdivide(mesh: trimesh.Trimesh, times: int) -> trimesh.Trimesh:
    visual = mesh.visual
    attributes: dict[str, np.ndarray] = {}
    uv = getattr(visual, "uv", None)
    if isinstance(visual, trimesh.visual.TextureVisuals) and uv is not None and len(uv) == len(mesh.vertices):
        attributes["uv"] = np.asarray(uv, dtype=np.float64)
    elif visual.kind == "vertex":
        attributes["rgba"] = np.asarray(visual.vertex_colors, dtype=np.float64)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    for _ in range(times):
        # Face i becomes faces 4i..4i+3, its corners' attributes averaged at the edge midpoints.
        vertices, faces, attributes = trimesh.remesh.subdivide(vertices, faces, vertex_attributes=attributes)
    per_face = 4**times
    metadata = {k: np.repeat(v, per_face) if k in (FACE_SEMANTIC, FACE_INSTANCE) else v for k, v in mesh.metadata.items()}
    out = trimesh.Trimesh(vertices, faces, process=False, metadata=metadata)
    if "uv" in attributes:
        out.visual = trimesh.visual.TextureVisuals(uv=attributes["uv"], material=visual.material)
    elif "rgba" in attributes:
        out.visual = trimesh.visual.ColorVisuals(out, vertex_colors=np.rint(attributes["rgba"]).astype(np.uint8))
    elif visual.kind == "face":
        out.visual = trimesh.visual.ColorVisuals(out, face_colors=np.repeat(visual.face_colors, per_face, axis=0))
    return out


def _planar_uv(vertices: np.ndarray) -> np.ndarray:
    """Texture coordinates from a projection on the two longest axes (enough to look textured)."""
    span = np.ptp(vertices, axis=0)
    axes = np.argsort(span)[::-1][:2]
    return (vertices[:, axes] - vertices[:, axes].min(axis=0)) / np.maximum(span[axes], 1e-9)


FURNITURE = (
    # name, (width range, depth range, height), where: along a wall or free-standing
    ("desk", (1.2, 1.6), (0.6, 0.8), 0.75, "wall"),
    ("shelf", (0.8, 1.2), (0.3, 0.45), 1.9, "wall"),
    ("cabinet", (0.4, 0.6), (0.4, 0.6), 1.0, "wall"),
    ("chair", (0.45, 0.55), (0.45, 0.55), 0.9, "free"),
)
"""The pieces :func:`furnished_room` draws from, in turn."""


def furnished_room(
    size: tuple[float, float], *, seed: int = 0, corner: tuple[float, float] = (0.0, 0.0), pieces: int = 4
) -> trimesh.Scene:
    """A closed room of ``size`` metres (inside) with its inner corner at ``corner``, and
    ``pieces`` boxes of furniture: desks, shelves (taller than the camera) and cabinets
    against random walls, chairs standing free in the middle half. A stand-in for a small
    scanned room, for the protocol's tests and measurements.
    """
    rng = np.random.default_rng(seed)
    sx, sy = size
    scene = box_room(size=size, crates=False)
    for k in range(pieces):
        name, (w0, w1), (d0, d1), height, where = FURNITURE[k % len(FURNITURE)]
        width, depth = rng.uniform(w0, w1), rng.uniform(d0, d1)
        if where == "free":
            extents, (x, y) = (width, depth), rng.uniform(-0.25, 0.25, 2) * (sx, sy)
        else:
            wall, along = int(rng.integers(4)), rng.uniform(-0.5, 0.5)
            if wall < 2:  # north or south: along x
                extents, x, y = (width, depth), along * (sx - width), (1 - 2 * wall) * (sy - depth) / 2
            else:  # east or west: along y
                extents, x, y = (depth, width), (5 - 2 * wall) * (sx - depth) / 2, along * (sy - width)
        box = solid_box((*extents, height), (x, y, height / 2), (150, 110, 70, 255))
        box.metadata.update(semantic_id=CRATE, instance_id=100 + k)
        scene.add_geometry(box, geom_name=f"{name}_{k}")
    scene.apply_translation((corner[0] + sx / 2, corner[1] + sy / 2, 0.0))
    return scene
