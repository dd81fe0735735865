"""Writing a home to disk: a y-up GLB, its semantic sidecar and its floor plan.

``export_glb(home, "home.glb")`` writes, each file atomically,

* ``home.glb``: every object as a named, textured or vertex-coloured mesh, in the
  y-up frame of glTF and Habitat-Sim: ``(x_h, y_h, z_h) = (x, z, -y)``;
* ``home.semantic.json``: ``{"categories": {name: id}, "geometries": {geometry name:
  {"category", "semantic_id", "instance_id"}}}``;
* ``home.floorplan.json``: the floor plan in the core's format
  (:meth:`ssga_bench.workspace.FloorPlan.to_json`).

These are what the mesh workspace source reads (``ssga_workspace_mesh.load_mesh_scene``
and its floor-plan lookup beside the mesh), so an exported home opens as a ``mesh``
workspace too.
"""

from __future__ import annotations

import os
from pathlib import Path

from ssga_bench import write_json
from ssga_workspace_mesh.loading import floor_plan_path, save_mesh_scene, sidecar_path
from ssga_workspace_procedural.categories import CATEGORIES
from ssga_workspace_procedural.home import Home


def export_glb(home: Home, path: str | os.PathLike[str]) -> tuple[Path, Path, Path]:
    """Write ``home`` as a y-up GLB plus its semantic and floor-plan sidecars; returns the three paths."""
    glb = Path(path)
    save_mesh_scene(home.scene, glb, ids=home.ids(), categories=dict(CATEGORIES), up_axis="y")
    plan = floor_plan_path(glb)
    write_json(plan, home.floor_plan.to_json())
    return glb, sidecar_path(glb), plan
