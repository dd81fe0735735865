"""The ``mesh`` workspace source: any GLB/glTF or OBJ scene, rendered by ray casting.

trimesh, Embree and OpenCV are imported in :meth:`MeshWorkspaceSource.open`, not
here, so that discovering plugins (``ssga plugins``, config validation) does not pay
the better part of a second for a workspace that may never be opened.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pydantic import Field

from ssga_core import Camera, Data, Pose, StageConfig, View, WorkspaceSource, hookimpl
from ssga_bench import FloorPlan, Workspace

if TYPE_CHECKING:
    from ssga_workspace_mesh.renderer import MeshRenderer


class MeshConfig(StageConfig):
    """Which mesh file, how to read it, and the camera its views are taken with."""

    path: Path = Field(description="The mesh file: .glb, .gltf or .obj (with its .mtl and textures beside it); relative to the config file.")
    up_axis: Literal["y", "z"] = Field(
        default="y", description="The file's up axis: 'y' for glTF/Habitat/HM3D files, 'z' for files already in ssga's frame."
    )
    floor_plan: Path | None = Field(
        default=None,
        description="JSON floor plan (free and occluder polygons). If omitted: <mesh stem>.floorplan.json beside the mesh "
        "when there is one, else derived from the mesh.",
    )
    width: int = Field(default=256, gt=0, le=4096, description="Image width, pixels.")
    height: int = Field(default=256, gt=0, le=4096, description="Image height, pixels.")
    hfov_deg: float = Field(default=90.0, gt=0.0, lt=180.0, description="Horizontal field of view, degrees.")
    camera_height: float = Field(
        default=1.5, gt=0.0, description="Camera height above the floor, metres: where the protocol's viewpoints stand, and the floor plan's cut."
    )
    shading: bool = Field(default=True, description="Shade surfaces by their angle to a fixed light, so flat walls read.")


@dataclass(frozen=True, eq=False)
class MeshWorkspace:
    """A mesh scene with its camera and floor plan (satisfies :class:`ssga_bench.workspace.Workspace`)."""

    name: str
    camera: Camera
    floor_plan: FloorPlan
    renderer: MeshRenderer
    camera_height: float = 1.5

    def render(self, pose: Pose) -> View:
        return self.renderer.render(pose)


class MeshWorkspaceSource(WorkspaceSource):
    """Views of a triangle mesh: RGB from its textures or colours, planar depth, semantic and instance ids."""

    name = "mesh"
    Config = MeshConfig
    produces = frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})

    def open(self) -> Workspace:
        from ssga_workspace_mesh.floorplan import floor_plan_from_mesh, load_floor_plan
        from ssga_workspace_mesh.loading import floor_plan_path, load_mesh_scene
        from ssga_workspace_mesh.renderer import MeshRenderer

        config: MeshConfig = self.config  # type: ignore[assignment]
        scene, ids = load_mesh_scene(config.path, up_axis=config.up_axis)
        camera = Camera(width=config.width, height=config.height, hfov_deg=config.hfov_deg)
        plan_file = config.floor_plan or floor_plan_path(config.path)
        if config.floor_plan or plan_file.exists():
            plan = load_floor_plan(plan_file)
        else:
            plan = floor_plan_from_mesh(scene, camera_height=config.camera_height, source=str(config.path))
        renderer = MeshRenderer(scene, camera, ids=ids, shading=config.shading)
        return MeshWorkspace(name=config.path.stem, camera=camera, floor_plan=plan, renderer=renderer, camera_height=config.camera_height)


@hookimpl
def ssga_register_workspaces() -> list[type[WorkspaceSource]]:
    return [MeshWorkspaceSource]
