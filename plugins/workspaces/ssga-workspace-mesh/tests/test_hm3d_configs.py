"""The ready configs of the paper's three HM3D scenes (examples/hm3d) validate, and say what they miss."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from ssga_workspace_mesh.plugin import MeshConfig, MeshWorkspaceSource, scene_name

from ssga_core import ConfigError
from ssga_core.testing import get_plugin_manager
from ssga_bench import load_experiment

EXAMPLES = Path(__file__).resolve().parents[4] / "examples" / "hm3d"
PAPER_SCENES = ("00800-TEEsavR23oF", "00801-HaxA7YrQdEC", "00802-wcojb4TFT35")


@pytest.mark.parametrize("scene", PAPER_SCENES)
def test_the_config_of_a_paper_scene_validates_and_names_its_files(scene):
    path = EXAMPLES / f"{scene}.toml"
    raw = tomllib.loads(path.read_text())
    assert raw["preset"] == "paper" and raw["workspace"]["name"] == "mesh"
    workspace = {k: v for k, v in raw["workspace"].items() if k != "name"}
    config = MeshConfig(**{**workspace, "path": EXAMPLES / workspace["path"]})
    assert config.path == EXAMPLES / "hm3d-minival-habitat-v0.2" / scene / f"{scene.split('-')[1]}.basis.glb"
    assert (config.width, config.height) == (256, 256), "the paper's image size"
    assert scene_name(config.path) == scene.split("-")[1]  # the workspace's name, without HM3D's ".basis"
    registry = get_plugin_manager().registry()
    if config.path.exists():
        experiment = load_experiment(path, registry)
        assert experiment.config.protocol.cells == 10 and experiment.config.protocol.cell_size == 2.0
    else:  # without the data: validation names the file, before anything runs
        assert MeshWorkspaceSource.missing(config) == [f"path: no such mesh file {config.path} (expected a .glb, .gltf, .obj or .ply file)"]
        with pytest.raises(ConfigError, match=r"workspace\.path: no such mesh file .*basis\.glb"):
            load_experiment(path, registry)
