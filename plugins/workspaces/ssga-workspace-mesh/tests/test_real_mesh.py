"""Real third-party textured meshes through the mesh workspace and the whole protocol.

pybullet ships, in its wheel, the textured OBJ assets of its examples (``pybullet_data``:
meshes, MTL files and images made by its authors, none of them ssga's): a checker-textured
ground plane, a table with a wood texture, a tray, a duck, a domino. It ships no textured
room, so the room here is made of those assets as pybullet's own URDFs place and scale them:
its floor, walls and ceiling are pybullet's plane (each wall with another of pybullet's
images), the table is ``table.urdf``'s five boxes, and a domino scaled to a bookcase gives
something taller than the camera to block sight. The room is written tilted, as a scan
would come, and read with ``up_axis = "auto"``.
"""

from __future__ import annotations

import csv
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from typer.testing import CliRunner

from ssga_core import Pose
from ssga_core.cli import app_with_plugin_commands
from ssga_workspace_mesh.loading import save_mesh_scene
from ssga_workspace_mesh.plugin import MeshConfig, MeshWorkspaceSource

pybullet_data = pytest.importorskip("pybullet_data", reason="pybullet (its wheel ships pybullet_data) is a test requirement")
DATA = Path(pybullet_data.getDataPath())

ROOM = (5.0, 4.0, 2.6)
"""Inside width, depth and height of the room, metres."""


def urdf_visuals(urdf: Path, name: str) -> list[tuple[str, trimesh.Trimesh]]:
    """The visual meshes of a URDF, each scaled and placed by its ``<origin>`` as pybullet does."""
    parts = []
    for k, visual in enumerate(ET.parse(urdf).getroot().iter("visual")):
        mesh = visual.find("geometry/mesh")
        if mesh is None:
            continue
        origin = visual.find("origin")
        xyz = [float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]
        rpy = [float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
        geom = trimesh.load(urdf.parent / mesh.get("filename"), force="mesh")
        geom.apply_transform(np.diag([*(float(v) for v in mesh.get("scale", "1 1 1").split()), 1.0]))
        place = trimesh.transformations.euler_matrix(*rpy, "sxyz")  # URDF: fixed-axis roll, pitch, yaw
        place[:3, 3] = xyz
        geom.apply_transform(place)
        parts.append((f"{name}_{k}", geom))
    return parts


def plane(size: tuple[float, float], transform: np.ndarray, image: str | None = None) -> trimesh.Trimesh:
    """pybullet's 30 x 30 m textured ground plane cut to ``size``, its texture repeating every 2 m
    as before (or another of pybullet's images in its place), placed by ``transform``."""
    quad = trimesh.load(DATA / "plane.obj", force="mesh")
    quad.apply_transform(np.diag([size[0] / 30.0, size[1] / 30.0, 1.0, 1.0]))
    quad.visual.uv = quad.visual.uv * (np.asarray(size) / 30.0)
    if image is not None:
        quad.visual.material.image = Image.open(DATA / image).convert("RGB")
    quad.apply_transform(transform)
    return quad


def at(xyz, rotation=None) -> np.ndarray:
    transform = np.eye(4) if rotation is None else rotation.copy()
    transform[:3, 3] = xyz
    return transform


def pybullet_room() -> trimesh.Scene:
    """The room (z up, floor at z = 0, corner at the origin), every surface facing into it."""
    w, d, h = ROOM
    turn = trimesh.transformations.rotation_matrix
    parts: list[tuple[str, trimesh.Trimesh]] = [
        ("floor", plane((w, d), at((w / 2, d / 2, 0.0)))),
        ("ceiling", plane((w, d), at((w / 2, d / 2, h), turn(math.pi, [1, 0, 0])), image="tex256.png")),
        # The plane faces +z; each wall is it stood up and turned to face the room.
        ("wall_south", plane((w, h), at((w / 2, 0.0, h / 2), turn(-math.pi / 2, [1, 0, 0])), image="uvmap.png")),
        ("wall_north", plane((w, h), at((w / 2, d, h / 2), turn(math.pi / 2, [1, 0, 0])), image="checker_grid.jpg")),
        ("wall_west", plane((h, d), at((0.0, d / 2, h / 2), turn(math.pi / 2, [0, 1, 0])), image="table/table.png")),
        ("wall_east", plane((h, d), at((w, d / 2, h / 2), turn(-math.pi / 2, [0, 1, 0])), image="tray/tray.jpg")),
    ]
    table = urdf_visuals(DATA / "table" / "table.urdf", "table")
    for _, part in table:
        part.apply_translation((1.4, 2.9, 0.0))
    tray = urdf_visuals(DATA / "tray" / "tray.urdf", "tray")
    for _, part in tray:
        part.apply_translation((1.4, 2.9, 0.625))  # on the table's top
    duck = trimesh.load(DATA / "duck.obj", force="mesh")  # y up in its file: stood up, 0.9 m tall
    duck.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))
    duck.apply_scale(0.6)
    duck.apply_translation((3.8 - duck.centroid[0], 1.0 - duck.centroid[1], -duck.bounds[0, 2]))
    bookcase = trimesh.load(DATA / "domino" / "domino.obj", force="mesh")
    bookcase.apply_transform(np.diag([*(np.array([0.3, 1.2, 2.0]) / bookcase.extents), 1.0]))
    bookcase.apply_translation((4.8 - bookcase.centroid[0], 2.6 - bookcase.centroid[1], -bookcase.bounds[0, 2]))
    scene = trimesh.Scene()
    for name, geom in [*parts, *table, *tray, ("duck", duck), ("bookcase", bookcase)]:
        scene.add_geometry(geom, geom_name=name)
    return scene


@pytest.fixture(scope="module")
def room_file(tmp_path_factory) -> Path:
    """The room written as one GLB, turned 25 degrees off level about a slanted axis, as a scan comes."""
    scene = pybullet_room()
    scene.apply_transform(trimesh.transformations.rotation_matrix(math.radians(25.0), [1.0, 2.0, 0.5]))
    path = tmp_path_factory.mktemp("pybullet") / "room.glb"
    save_mesh_scene(scene, path, up_axis="z")
    return path


def test_the_real_textures_render_on_the_levelled_room(room_file, capsys):
    workspace = MeshWorkspaceSource(MeshConfig(path=room_file, up_axis="auto", width=128, height=128)).open()
    assert "found up" in capsys.readouterr().err
    levelling = workspace.levelling
    true_up = trimesh.transformations.rotation_matrix(math.radians(25.0), [1.0, 2.0, 0.5])[:3, 2]
    assert math.degrees(math.acos(np.clip(levelling.up @ true_up, -1, 1))) < 0.5
    view = workspace.render(Pose(2.5, 0.8, math.pi / 2, 1.5))  # from the south wall towards the table
    names = list(trimesh.load(room_file, force="scene").geometry)
    floor = view.instance == names.index("floor")
    table = view.instance == names.index("table_0")
    assert floor.sum() > 500 and table.sum() > 50
    # The floor shows pybullet's blue-and-white checker, the table top its wood, not flat base colours.
    floor_rgb = view.rgb[floor].astype(float)
    assert floor_rgb.std(axis=0).max() > 20 and floor_rgb[:, 2].mean() > floor_rgb[:, 0].mean()
    wood = view.rgb[table].astype(float)
    assert wood.std(axis=0).max() > 5 and wood[:, 0].mean() > wood[:, 2].mean()
    # The derived floor plan finds the room, less the table, the duck and the bookcase.
    plan = workspace.floor_plan
    assert 0.6 * 5.0 * 4.0 < plan.free.area < 5.0 * 4.0
    assert plan.can_stand(2.5, 2.0) and not plan.can_stand(1.4, 2.9) and not plan.can_stand(4.8, 2.6)


@pytest.mark.slow
def test_a_real_textured_room_through_the_whole_protocol(room_file, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the workspace dataset goes under ./runs
    config = tmp_path / "exp.toml"
    config.write_text(
        f'output = "{tmp_path / "out"}"\nvariants = ["PD", "SD", "D"]\n'
        f'[workspace]\nname = "mesh"\npath = "{room_file}"\nup_axis = "auto"\nwidth = 128\nheight = 128\n'
        "[protocol]\ncells = 5\ntest_per_class = 1\nseed = 1\n"  # the default 2 m cells: too large for 5 in this room
        '[stages]\nparser = { name = "slico", preset = "coarse" }\ndescriptor = { name = "dense-sift", bow = { k = 16 } }\n'
        'synthesizer = { name = "depth-warp" }\n[training]\nepochs = 5\nhidden = 32\nsynthetic_per_class = 1\n'
    )
    result = CliRunner().invoke(app_with_plugin_commands(), ["run", str(config)])
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader((tmp_path / "out" / "results.csv").open()))
    assert {"SIFT-SL (PD)", "SIFT (SD)", "SIFT (D)", "Ensemble (RRF)"} <= {r["row"] for r in rows}
    assert int(next(r for r in rows if r["group"] == "all")["n"]) == 5 * 12
    dataset = json.loads(next((tmp_path / "runs" / "workspaces").glob("room-*/dataset.json")).read_text())
    assert dataset["source"]["up_axis"] == "auto"
    # A scan fits the protocol to itself on the first try (protocol.fit: the mesh source's default), says so and records it.
    fitted = json.loads((tmp_path / "out" / "protocol-fitted.json").read_text())
    assert fitted["configured"]["cell_size"] == 2.0 and fitted["fitted"]["cell_size"] < 2.0
    assert "the protocol was fitted to it: protocol.cell_size" in result.output
    assert "The protocol was fitted to this workspace" in (tmp_path / "out" / "index.html").read_text()
