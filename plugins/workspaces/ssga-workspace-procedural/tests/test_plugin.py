"""The plugin: discovery, config validation, and the opened workspace."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from ssga_core import Data
from ssga_core.testing import get_plugin_manager
from ssga_bench import Workspace
from ssga_workspace_procedural.plugin import ProceduralConfig, ProceduralWorkspaceSource


def test_the_plugin_is_discovered() -> None:
    registry = get_plugin_manager().registry()
    assert not [f for f in registry.failures if "procedural" in str(f)]
    cls = registry.get("workspace", "procedural")
    assert cls is ProceduralWorkspaceSource
    assert cls.produces == frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})


def test_every_config_field_is_described() -> None:
    for name, field in ProceduralConfig.model_fields.items():
        assert field.description, name


@pytest.mark.parametrize(
    "params",
    [{"seed": -1}, {"rooms": 0}, {"rooms": 9}, {"furniture_density": 3.0}, {"hfov_deg": 180.0}, {"camera_height": 2.6},
     {"rooms": 8, "home_width": 6.0, "home_depth": 6.0}, {"colour": "red"}],
)  # fmt: skip
def test_bad_configs_fail_validation(params: dict) -> None:
    with pytest.raises(ValidationError):
        ProceduralConfig.model_validate(params)


def test_open_gives_a_workspace() -> None:
    source = (
        get_plugin_manager().registry().create("workspace", "procedural", seed=7, rooms=3, width=64, height=48, hfov_deg=70.0)
    )
    ws = source.open()
    assert isinstance(ws, Workspace)
    assert ws.name == "procedural-7"
    assert ws.camera.shape == (48, 64) and ws.camera.hfov_deg == 70.0
    assert len(ws.home.rooms) == 3
    assert ws.floor_plan is ws.home.floor_plan
    pose = ws.home.sample_poses(1, np.random.default_rng(0))[0]
    assert ws.render(pose).available == frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})


def test_a_low_camera_makes_lower_furniture_occlude() -> None:
    low = ProceduralWorkspaceSource(ProceduralConfig(seed=2, camera_height=0.8)).open()
    assert low.home.config.occluder_height == 0.8
