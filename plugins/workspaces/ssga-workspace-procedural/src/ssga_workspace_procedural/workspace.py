"""The opened workspace: a generated home, its camera, and a renderer built on first use."""

from __future__ import annotations

import os
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

from ssga_core import Camera, Pose, View
from ssga_bench import FloorPlan
from ssga_workspace_procedural.home import Home

if TYPE_CHECKING:
    from ssga_workspace_mesh.renderer import MeshRenderer


class ProceduralWorkspace:
    """A procedural home seen through ``camera`` (satisfies :class:`ssga_bench.workspace.Workspace`).

    The renderer (an Embree scene over every triangle) is built on the first
    :meth:`render`, so opening a workspace only to read its floor plan stays cheap.
    """

    def __init__(self, home: Home, camera: Camera, *, camera_height: float = 1.5, shading: bool = True) -> None:
        self.home = home
        self.camera = camera
        self.camera_height = camera_height
        self.shading = shading
        self.name = f"procedural-{home.config.seed}"

    @property
    def floor_plan(self) -> FloorPlan:
        return self.home.floor_plan

    @cached_property
    def renderer(self) -> MeshRenderer:
        from ssga_workspace_mesh.renderer import MeshRenderer

        return MeshRenderer(self.home.scene, self.camera, ids=self.home.ids(), shading=self.shading)

    def render(self, pose: Pose) -> View:
        """RGB, planar depth and semantic/instance ids from ``pose`` (its own height is used)."""
        return self.renderer.render(pose)

    def export(self, path: str | os.PathLike[str]) -> tuple[Path, Path, Path]:
        """Write the home as a y-up GLB with its sidecars (see :func:`~ssga_workspace_procedural.export.export_glb`)."""
        from ssga_workspace_procedural.export import export_glb

        return export_glb(self.home, path)

    def __repr__(self) -> str:
        return f"ProceduralWorkspace({self.name!r}, {len(self.home.rooms)} rooms, {self.home.triangle_count} triangles)"
