"""GLB export: the y-up file, its sidecars, and reading them back with the mesh plugin."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ssga_core import Camera
from ssga_workspace_procedural import Home, export_glb


@pytest.fixture(scope="module")
def exported(home: Home, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    return export_glb(home, tmp_path_factory.mktemp("export") / "home.glb")


def test_export_writes_the_glb_and_its_sidecars_atomically(exported: tuple[Path, Path, Path]) -> None:
    glb, semantic, plan = exported
    assert (glb.name, semantic.name, plan.name) == ("home.glb", "home.semantic.json", "home.floorplan.json")
    assert glb.read_bytes()[:4] == b"glTF"
    assert sorted(p.name for p in glb.parent.iterdir()) == sorted([glb.name, semantic.name, plan.name])  # no temp files left


def test_glb_round_trip_keeps_geometry_and_ids(home: Home, exported: tuple[Path, Path, Path]) -> None:
    from ssga_workspace_mesh import load_mesh_scene

    scene, ids = load_mesh_scene(exported[0], up_axis="y")
    np.testing.assert_allclose(scene.bounds, home.scene.bounds, atol=1e-5)
    assert ids == home.ids()
    data = json.loads(exported[1].read_text())
    assert data["geometries"]["wall-0001"] == {"category": "wall", "semantic_id": 1, "instance_id": 1}


def test_the_glb_renders_like_the_home(home: Home, exported: tuple[Path, Path, Path]) -> None:
    from ssga_workspace_mesh import MeshRenderer, load_mesh_scene

    camera = Camera(96, 96, 90.0)
    scene, ids = load_mesh_scene(exported[0])
    original, loaded = MeshRenderer(home.scene, camera, ids=home.ids()), MeshRenderer(scene, camera, ids=ids)
    for pose in home.sample_poses(3, np.random.default_rng(5)):
        a, b = original.render(pose), loaded.render(pose)
        assert (a.instance == b.instance).mean() > 0.995
        np.testing.assert_allclose(a.depth, b.depth, atol=1e-3)
        assert np.abs(a.rgb.astype(int) - b.rgb.astype(int)).mean() < 2.0


def test_the_floor_plan_file_reads_back_as_the_same_plan(home: Home, exported: tuple[Path, Path, Path]) -> None:
    from ssga_workspace_mesh import load_floor_plan

    data = json.loads(exported[2].read_text())
    assert set(data) == {"free", "occluders"}
    plan = load_floor_plan(exported[2])
    assert plan.free.symmetric_difference(home.floor_plan.free).area < 1e-4
    assert plan.occluders.symmetric_difference(home.floor_plan.occluders).area < 1e-4
