"""The plugin as ssga sees it: discovered, configured, opened."""

from __future__ import annotations

import json

import pydantic
import pytest
import shapely

from ssga_core import Data, InputError, Pose
from ssga_core.testing import get_plugin_manager
from ssga_bench import Workspace
from ssga_workspace_mesh.loading import save_mesh_scene
from ssga_workspace_mesh.plugin import MeshConfig, MeshWorkspaceSource
from ssga_workspace_mesh.scenes import WALL, box_room


@pytest.fixture(scope="module")
def house(tmp_path_factory):
    """box_room as a y-up GLB with a sidecar, as the procedural generator writes houses."""
    path = tmp_path_factory.mktemp("mesh") / "house.glb"
    save_mesh_scene(box_room(), path)
    return path


def test_is_discovered_through_its_entry_point():
    registry = get_plugin_manager().registry()
    assert registry.get("workspace", "mesh") is MeshWorkspaceSource
    assert registry.entry("workspace", "mesh").plugin.distribution == "ssga-workspace-mesh"
    assert MeshWorkspaceSource.produces == {Data.RGB, Data.DEPTH, Data.SEMANTIC}


@pytest.mark.parametrize("bad", [{"hfov_deg": 200}, {"up_axis": "x"}, {"width": 0}, {"colour": "red"}])
def test_bad_config_fails_validation(bad):
    registry = get_plugin_manager().registry()
    with pytest.raises(pydantic.ValidationError):
        registry.create("workspace", "mesh", path="house.glb", **bad)


def test_open_gives_a_workspace_that_renders(house):
    workspace = MeshWorkspaceSource(MeshConfig(path=str(house), width=128, height=96, hfov_deg=80)).open()
    assert isinstance(workspace, Workspace)
    assert workspace.name == "house"
    assert workspace.camera.shape == (96, 128)
    x, y = shapely.get_coordinates(workspace.floor_plan.free.representative_point())[0]
    view = workspace.render(Pose(x, y, 0.0, 1.5))
    assert view.camera == workspace.camera and view.valid_depth().all()
    assert (view.semantic == WALL).any() and view.available == {Data.RGB, Data.DEPTH, Data.SEMANTIC}


def test_open_with_a_json_floor_plan(house, tmp_path):
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"free": [[[-1, -1], [1, -1], [1, 1], [-1, 1]]]}))
    workspace = MeshWorkspaceSource(MeshConfig(path=str(house), floor_plan=str(plan))).open()
    assert workspace.floor_plan.free.area == pytest.approx(4.0)


def test_open_finds_a_floor_plan_beside_the_mesh(tmp_path):
    save_mesh_scene(box_room(), tmp_path / "home.glb")
    (tmp_path / "home.floorplan.json").write_text(json.dumps({"free": [[[0, 0], [2, 0], [2, 1], [0, 1]]]}))
    workspace = MeshWorkspaceSource(MeshConfig(path=str(tmp_path / "home.glb"))).open()
    assert workspace.floor_plan.free.area == pytest.approx(2.0)


def test_open_a_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="nowhere.glb"):
        MeshWorkspaceSource(MeshConfig(path=str(tmp_path / "nowhere.glb"))).open()
