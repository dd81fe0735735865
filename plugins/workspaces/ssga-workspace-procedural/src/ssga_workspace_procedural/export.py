"""Writing a home to disk: a y-up GLB, its semantic sidecar and its floor plan.

``export_glb(home, "home.glb")`` writes

* ``home.glb``: every object as a named, textured or vertex-coloured mesh, in the
  y-up frame of glTF and Habitat-Sim: ``(x_h, y_h, z_h) = (x, z, -y)``;
* ``home.semantic.json``: ``{"categories": {name: id}, "geometries": {geometry name:
  {"category", "semantic_id", "instance_id"}}}``, what
  ``ssga_workspace_mesh.renderer.load_mesh_scene`` reads back;
* ``home.floorplan.json``: ``{"free": [ring, ...], "occluders": [ring, ...]}``, each ring a
  polygon's exterior ``[[x, y], ...]`` in ssga's world frame (metres). A region is the
  *union* of its rings; since rings carry no holes, the free floor (which has holes
  where furniture stands) is cut into hole-free pieces first.

Each file is written to a temporary name and renamed into place, so a reader never sees
half a file.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import shapely
import trimesh
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import split

from ssga_workspace_procedural.categories import CATEGORIES
from ssga_workspace_procedural.generator import Home

Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, -1.0, 0, 0], [0, 0, 0, 1.0]])
"""ssga's z-up world to glTF/Habitat's y-up: ``(x, y, z) -> (x, z, -y)`` (a rotation)."""


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def hole_free_parts(region: BaseGeometry) -> list[Polygon]:
    """Polygons without holes whose union is ``region``.

    Each hole is cut open by a vertical line through its middle, which splits the
    polygon around it into pieces that no longer enclose it.
    """
    out: list[Polygon] = []
    for poly in getattr(region, "geoms", [region]):
        if poly.is_empty or poly.geom_type != "Polygon":
            continue
        if not poly.interiors:
            out.append(poly)
            continue
        y0, y1 = poly.bounds[1] - 1.0, poly.bounds[3] + 1.0
        pieces = [poly]
        for hole in poly.interiors:
            hx0, _, hx1, _ = hole.bounds
            cut = shapely.LineString([((hx0 + hx1) / 2, y0), ((hx0 + hx1) / 2, y1)])
            pieces = [g for p in pieces for g in split(p, cut).geoms]
        out += hole_free_parts(shapely.MultiPolygon(pieces)) if any(p.interiors for p in pieces) else pieces
    return out


def _rings(polygons: Iterable[Polygon]) -> list[list[list[float]]]:
    return [[[round(x, 6), round(y, 6)] for x, y in p.exterior.coords] for p in polygons]


def floor_plan_json(home: Home) -> dict[str, list]:
    """The floor plan in the exported format (see the module docstring)."""
    return {"free": _rings(hole_free_parts(home.floor_plan.free)), "occluders": _rings(home.occluder_parts)}


def semantic_json(home: Home) -> dict[str, dict]:
    """The semantic sidecar's contents (see the module docstring)."""
    return {
        "categories": dict(CATEGORIES),
        "geometries": {
            o.name: {"category": o.category, "semantic_id": o.semantic_id, "instance_id": o.instance_id} for o in home.objects
        },
    }


def y_up_scene(home: Home) -> trimesh.Scene:
    """The home's scene with every mesh turned into the y-up frame (baked into the vertices)."""
    scene = trimesh.Scene()
    for name, mesh in home.scene.geometry.items():
        turned = mesh.copy()
        turned.apply_transform(Y_UP)
        scene.add_geometry(turned, geom_name=name, node_name=name)
    return scene


def sidecar_paths(path: str | os.PathLike[str]) -> tuple[Path, Path, Path]:
    """``(glb, semantic.json, floorplan.json)`` paths for an export to ``path``."""
    glb = Path(path)
    stem = glb.with_suffix("")
    return glb, stem.with_name(stem.name + ".semantic.json"), stem.with_name(stem.name + ".floorplan.json")


def export_glb(home: Home, path: str | os.PathLike[str]) -> tuple[Path, Path, Path]:
    """Write ``home`` as a y-up GLB plus its semantic and floor-plan sidecars; returns the three paths."""
    glb, semantic, plan = sidecar_paths(path)
    glb.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(glb, y_up_scene(home).export(file_type="glb"))
    write_atomic(semantic, json.dumps(semantic_json(home), indent=1).encode())
    write_atomic(plan, json.dumps(floor_plan_json(home)).encode())
    return glb, semantic, plan
