"""ssga workspace source rendering views of a textured triangle mesh by ray casting.

The public names are imported on first use, so that loading the plugin module
(which only registers :class:`~ssga_workspace_mesh.plugin.MeshWorkspaceSource`)
does not import trimesh, Embree and OpenCV.
"""

from __future__ import annotations

from ssga_core import lazy_exports

_EXPORTS = {
    "MeshRenderer": "ssga_workspace_mesh.renderer",
    "load_mesh_scene": "ssga_workspace_mesh.loading",
    "save_mesh_scene": "ssga_workspace_mesh.loading",
    "sidecar_path": "ssga_workspace_mesh.loading",
    "read_semantic_table": "ssga_workspace_mesh.hm3d",
    "subdivided": "ssga_workspace_mesh.scenes",
    "floor_plan_from_mesh": "ssga_workspace_mesh.floorplan",
    "floor_plan_for_scan": "ssga_workspace_mesh.floorplan",
    "read_ply": "ssga_workspace_mesh.ply",
    "load_floor_plan": "ssga_workspace_mesh.floorplan",
    "MeshWorkspace": "ssga_workspace_mesh.plugin",
    "MeshWorkspaceSource": "ssga_workspace_mesh.plugin",
}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
