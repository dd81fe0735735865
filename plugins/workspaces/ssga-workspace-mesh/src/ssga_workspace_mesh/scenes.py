"""Small synthetic scenes with known geometry, for tests, benchmarks and examples.

They are built in ssga's world frame (z up, metres, floor top at ``z = 0``) and carry
their ids in ``metadata["semantic_id"]`` / ``["instance_id"]``, as the renderer reads.
"""

from __future__ import annotations

import numpy as np
import trimesh
from PIL import Image
from trimesh.visual.material import PBRMaterial

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


def _planar_uv(vertices: np.ndarray) -> np.ndarray:
    """Texture coordinates from a projection on the two longest axes (enough to look textured)."""
    span = np.ptp(vertices, axis=0)
    axes = np.argsort(span)[::-1][:2]
    return (vertices[:, axes] - vertices[:, axes].min(axis=0)) / np.maximum(span[axes], 1e-9)
