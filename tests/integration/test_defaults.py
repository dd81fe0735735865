"""Defaults work together: what a new user types first runs, whatever the seed."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from ssga_bench.config import load_experiment, packaged_config, validate_experiment
from ssga_bench.protocol import Protocol
from ssga_core.cli import app_with_plugin_commands
from ssga_core.config import resolve_stage


@pytest.mark.parametrize("seed", range(6))
def test_the_demo_workspace_has_its_cells_on_every_seed(seed, ssga_installed_registry):
    demo = load_experiment(packaged_config("demo.toml"), ssga_installed_registry)
    options = {**demo.workspace.config.model_dump(), "seed": seed}
    workspace = resolve_stage("workspace", {"name": demo.workspace.name, **options}, ssga_installed_registry).create().open()
    protocol = demo.config.protocol.model_copy(update={"seed": seed})
    plan = Protocol(workspace.floor_plan, workspace.camera, protocol).plan(workspace.name, workspace.camera_height)
    assert len(plan.cells) == protocol.cells


@pytest.mark.parametrize("seed", range(2))
def test_a_config_without_a_workspace_has_room_for_the_default_cells(seed, ssga_installed_registry):
    protocol = {"seed": seed, "test_per_class": 1}  # the cells are the point, not the test views
    bare = validate_experiment({"variants": ["D"], "stages": {"descriptor": {"name": "dense-sift"}}, "protocol": protocol}, ssga_installed_registry)
    options = {**bare.workspace.config.model_dump(), "seed": seed}
    workspace = resolve_stage("workspace", {"name": bare.workspace.name, **options}, ssga_installed_registry).create().open()
    plan = Protocol(workspace.floor_plan, workspace.camera, bare.config.protocol).plan(workspace.name, workspace.camera_height)
    assert len(plan.cells) == bare.config.protocol.cells == 10


def test_workspace_build_with_only_a_seed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app_with_plugin_commands(), ["workspace", "build", "--seed", "3", "--test-per-class", "1"])
    assert result.exit_code == 0, result.output
    assert "48 classes" in result.output
