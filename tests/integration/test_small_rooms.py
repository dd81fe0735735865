"""The protocol in a small scanned room (a mesh workspace's floor plan): cells of 1 m seen from all 12 headings, and what to change when there are too few."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from ssga_core import Camera, InputError
from ssga_core.cli import app_with_plugin_commands
from ssga_bench.protocol import FULL_REACH, VIEWPOINT_STEPS, Protocol, ProtocolConfig
from ssga_workspace_mesh.floorplan import floor_plan_from_mesh
from ssga_workspace_mesh.loading import save_mesh_scene
from ssga_workspace_mesh.scenes import furnished_room

OFFICE = {"size": (3.5, 4.4), "seed": 0, "corner": (0.25, 0.5), "pieces": 5}
"""A 3.5 x 4.4 m office (desks, a shelf, a cabinet, a chair) where only 3 cells of 1 m had a
canonical viewpoint 0.5 m or more behind them for every heading, so the protocol used to refuse it."""


@pytest.fixture(scope="module")
def office_plan():
    scene = furnished_room(OFFICE["size"], seed=OFFICE["seed"], corner=OFFICE["corner"], pieces=OFFICE["pieces"])
    return floor_plan_from_mesh(scene)


def test_a_small_office_yields_four_cells_of_one_metre_with_twelve_headings(office_plan):
    config = ProtocolConfig(cell_size=1.0, cells=4, orientations=12, test_per_class=1)
    protocol = Protocol(office_plan, Camera(), config)
    plan = protocol.plan("office")
    assert len(plan.cells) == 4 and plan.num_classes == 48
    canonical = plan.split("train") + plan.split("target")
    assert sorted(s.place for s in canonical) == list(range(48))
    reach = []
    for s in canonical:
        assert protocol.assign(np.array([[s.pose.x, s.pose.y]]), np.array([s.pose.yaw]))[0] == s.cell
        back = math.dist((s.pose.x, s.pose.y), protocol.centroids[s.cell]) / config.viewpoint_distance
        assert min(abs(back - step) for step in VIEWPOINT_STEPS) < 1e-9, "a viewpoint stands at one of the steps"
        reach.append(back)
    assert min(reach) < FULL_REACH, "the room needs viewpoints nearer than half the distance"


def test_too_many_cells_names_values_that_would_give_them(office_plan):
    config = ProtocolConfig(cell_size=1.0, cells=8, test_per_class=1)
    with pytest.raises(InputError) as raised:
        Protocol(office_plan, Camera(), config).plan("office")
    message = str(raised.value)
    assert "8 wanted" in message and "lower protocol.cells to" in message and "--suggest" in message
    # Every value the error suggests gives the cells when tried.
    named = re.findall(r"((?:protocol\.\w+ = [\d.]+(?: with )?)+) gives at least 8", message)
    assert named, message
    for values in named:
        tried = config.model_copy(update={k: float(v) for k, v in re.findall(r"protocol\.(\w+) = ([\d.]+)", values)})
        protocol = Protocol(office_plan, Camera(), tried)
        assert len(protocol.eligible_cells(protocol.free_cells(), 1.5)) >= 8, values


def test_workspace_build_suggest_prints_the_values_and_builds_nothing(tmp_path, monkeypatch):
    scene = furnished_room(OFFICE["size"], seed=OFFICE["seed"], corner=OFFICE["corner"], pieces=OFFICE["pieces"])
    save_mesh_scene(scene, tmp_path / "office.glb")
    monkeypatch.chdir(tmp_path)
    args = ["workspace", "build", "--source", "mesh", "-o", "path=office.glb", "--cell-size", "1", "--cells", "8", "--test-per-class", "1"]
    result = CliRunner().invoke(app_with_plugin_commands(), [*args, "--suggest"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    configured = next(line for line in lines if "<- configured" in line)
    assert configured.split()[:2] == ["1", "1"] and int(configured.split()[2]) < 8
    assert any(line.startswith("to get them: protocol.") for line in lines)
    assert any(line.startswith("test views (with protocol.") and "test_radius = " in line for line in lines)
    assert not (tmp_path / "runs").exists()
    # What it suggests first builds.
    first = next(line for line in lines if line.startswith("to get them: ")).split("; or ")[0]
    options = [arg for key, value in re.findall(r"protocol\.(\w+) = ([\d.]+)", first) for arg in (f"--{key.replace('_', '-')}", value)]
    result = CliRunner().invoke(app_with_plugin_commands(), [*args, "-o", "width=64", "-o", "height=64", *options])
    assert result.exit_code == 0, result.output
    assert "96 classes" in result.output
