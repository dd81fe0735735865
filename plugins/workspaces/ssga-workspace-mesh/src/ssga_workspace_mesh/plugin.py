"""The ``mesh`` workspace source: any GLB/glTF, OBJ or PLY scene, rendered by ray casting.

trimesh, Embree and OpenCV are imported in :meth:`MeshWorkspaceSource.open`, not
here, so that discovering plugins (``ssga plugins``, config validation) does not pay
the better part of a second for a workspace that may never be opened.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pydantic import Field, field_validator

from ssga_core import Camera, Data, Pose, StageConfig, View, WorkspaceSource, hookimpl
from ssga_bench import FloorPlan, Workspace

if TYPE_CHECKING:
    from ssga_workspace_mesh.gravity import Levelling
    from ssga_workspace_mesh.renderer import MeshRenderer


class MeshConfig(StageConfig):
    """Which mesh file, how to read it, and the camera its views are taken with."""

    path: Path = Field(
        description="The mesh file: .glb, .gltf, .obj (with its .mtl and textures beside it) or .ply (a scan; its TextureFile "
        "beside it, if any); relative to the config file."
    )
    up_axis: Literal["y", "z", "auto"] | tuple[float, float, float] = Field(
        default="y",
        description="The file's up: 'y' for glTF/Habitat/HM3D files, 'z' for files already in ssga's frame, 'auto' to find it "
        "from the mesh's floor, ceiling and walls (a scan in any orientation), or the floor's normal [x, y, z] in the file's "
        "frame. With 'auto' or a vector the mesh is levelled, its floor put at z = 0, and what was found is printed.",
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
        default=1.5,
        gt=0.0,
        description="Camera height above the floor, metres: where the protocol's viewpoints stand, and the floor plan's cut. "
        "Where a derived floor plan finds no geometry there (a scan whose walls end lower, as ScanNet's do near 1.4 m), "
        "0.8 x the height the walls reach is used instead, and a line says so.",
    )
    shading: bool = Field(default=True, description="Shade surfaces by their angle to a fixed light, so flat walls read.")

    @field_validator("up_axis", mode="before")
    @classmethod
    def _an_axis_or_a_direction(cls, value: object) -> object:
        # One message for every wrong value, rather than one per branch of the union.
        if value in ("y", "z", "auto"):
            return value
        numbers = isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        if not numbers or len(value) != 3 or not all(math.isfinite(v) for v in value) or not any(value):  # type: ignore[arg-type]
            raise ValueError(f"expected 'y', 'z', 'auto' or the floor's normal as a non-zero [x, y, z], got {value!r}")
        return value


@dataclass(frozen=True, eq=False)
class MeshWorkspace:
    """A mesh scene with its camera and floor plan (satisfies :class:`ssga_bench.workspace.Workspace`)."""

    name: str
    camera: Camera
    floor_plan: FloorPlan
    renderer: MeshRenderer
    camera_height: float = 1.5
    """Where views are taken: the configured height, or lower where the scan ends below it (:func:`.floorplan.floor_plan_for_scan`)."""
    levelling: Levelling | None = None
    """How the mesh was levelled (``up_axis = "auto"`` or a vector), else None."""

    def render(self, pose: Pose) -> View:
        return self.renderer.render(pose)


class MeshWorkspaceSource(WorkspaceSource):
    """Views of a triangle mesh: RGB from its textures or colours, planar depth, semantic and instance ids."""

    name = "mesh"
    fits_protocol = True  # a user's scan or captures: the protocol is fitted to them where it does not fit (protocol.fit)
    Config = MeshConfig
    produces = frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})

    @classmethod
    def missing(cls, config: StageConfig) -> list[str]:
        """The mesh file (there, readable, a format it reads, a header that holds), and a floor-plan
        file the config names, checked before anything runs."""
        from ssga_workspace_mesh.loading import mesh_file_problem

        assert isinstance(config, MeshConfig)
        problems = []
        problem = mesh_file_problem(config.path)
        if problem:
            problems.append(f"path: {problem}")
        if config.floor_plan is not None and not config.floor_plan.is_file():
            problems.append(f"floor_plan: no such file {config.floor_plan}")
        return problems

    def open(self) -> Workspace:
        from ssga_workspace_mesh.floorplan import floor_plan_for_scan, load_floor_plan
        from ssga_workspace_mesh.gravity import Levelling
        from ssga_workspace_mesh.loading import floor_plan_path, load_mesh_scene
        from ssga_workspace_mesh.renderer import MeshRenderer

        config: MeshConfig = self.config  # type: ignore[assignment]
        scene, ids = load_mesh_scene(config.path, up_axis=config.up_axis)
        levelling = scene.metadata.get("levelling")
        if not isinstance(levelling, Levelling):
            levelling = None  # not levelled here (a file may carry the record of an earlier levelling)
        else:
            # Said before anything runs, so a wrong guess is seen before a build renders it.
            print(f"{config.path}: {levelling.describe()}", file=sys.stderr)
        camera = Camera(width=config.width, height=config.height, hfov_deg=config.hfov_deg)
        plan_file = config.floor_plan or floor_plan_path(config.path)
        height = config.camera_height
        if config.floor_plan or plan_file.exists():
            plan = load_floor_plan(plan_file)
        else:
            plan, height, note = floor_plan_for_scan(scene, config.camera_height, source=str(config.path))
            if note:
                print(note, file=sys.stderr)
        renderer = MeshRenderer(scene, camera, ids=ids, shading=config.shading)
        return MeshWorkspace(name=scene_name(config.path), camera=camera, floor_plan=plan, renderer=renderer, camera_height=height, levelling=levelling)


def scene_name(path: Path) -> str:
    """The scene's name from its file: the stem, less HM3D's ``.basis`` (``TEEsavR23oF.basis.glb`` is ``TEEsavR23oF``)."""
    stem = path.stem
    return stem.removesuffix(".basis") or stem


@hookimpl
def ssga_register_workspaces() -> list[type[WorkspaceSource]]:
    return [MeshWorkspaceSource]
