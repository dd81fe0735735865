"""Loading GLB and OBJ files into ssga's frame, the semantic sidecar, and bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ssga_core import InputError, Pose
from ssga_workspace_mesh.loading import load_mesh_scene, save_mesh_scene, sidecar_path
from ssga_workspace_mesh.meshdata import geometry_ids
from ssga_workspace_mesh.renderer import MeshRenderer
from ssga_workspace_mesh.scenes import WALL, box_room, textured_quad

POSES = (Pose(0.0, 0.0, 0.0, 1.5), Pose(-1.0, 0.5, 2.2, 1.3), Pose(2.5, -2.0, -2.4, 1.6))


def test_glb_round_trip_renders_as_the_scene_in_memory(tmp_path, camera, pattern):
    scene = box_room()
    quad = textured_quad(np.array([[3.9, 1.0, 2.5], [3.9, -1.0, 2.5], [3.9, -1.0, 0.5], [3.9, 1.0, 0.5]]), pattern)
    quad.metadata.update(semantic_id=7, instance_id=70)
    scene.add_geometry(quad, geom_name="painting")
    sidecar = save_mesh_scene(scene, tmp_path / "room.glb", categories={"wall": WALL})
    assert json.loads(sidecar.read_text())["geometries"]["wall_east"]["category"] == "wall"

    loaded, ids = load_mesh_scene(tmp_path / "room.glb")
    assert ids == geometry_ids(scene) and ids["painting"] == (7, 70)
    np.testing.assert_allclose(loaded.bounds, scene.bounds, atol=1e-5)
    original, reloaded = MeshRenderer(scene, camera), MeshRenderer(loaded, camera, ids=ids)
    for pose in POSES:
        a, b = original.render(pose), reloaded.render(pose)
        np.testing.assert_allclose(a.depth, b.depth, atol=1e-4)
        same = (a.instance == b.instance).mean()
        assert same > 0.999, "only pixels on triangle edges may differ"
        assert (a.semantic == b.semantic).mean() > 0.999
        close = np.abs(a.rgb.astype(int) - b.rgb.astype(int)).max(axis=-1) <= 2
        assert close.mean() > 0.999
    assert (reloaded.render(POSES[0]).semantic == 7).any(), "the painting is in view"


def test_sidecar_categories_resolve_to_ids(tmp_path):
    scene = box_room(crates=False)
    scene.export(tmp_path / "flat.glb")
    sidecar_path(tmp_path / "flat.glb").write_text(
        json.dumps(
            {"categories": {"wall": 1, "floor": 2}, "geometries": {"floor": {"category": "floor"}, "ghost": {"semantic_id": 3}}}
        )
    )
    _, ids = load_mesh_scene(tmp_path / "flat.glb", up_axis="z")
    assert ids == {"floor": (2, list(scene.geometry).index("floor"))}, "names not in the file are ignored"


def test_up_axis_z_leaves_the_scene_alone(tmp_path):
    scene = box_room(crates=False)
    scene.export(tmp_path / "z.glb")
    loaded, ids = load_mesh_scene(tmp_path / "z.glb", up_axis="z")
    assert ids == {}
    np.testing.assert_allclose(loaded.bounds, scene.bounds, atol=1e-5)


def _write_obj_quad(folder: Path, image: np.ndarray, d: float = 2.0, h: float = 1.5) -> Path:
    """A y-up OBJ+MTL+PNG quad that, in ssga's frame, fills the view of a camera at the origin looking along +x."""
    Image.fromarray(image).save(folder / "paint.png")
    (folder / "quad.mtl").write_text("newmtl paint\nKd 1 1 1\nmap_Kd paint.png\n")
    # (x, y, z)_ssga = (x_h, -z_h, y_h): top-left of the view is ssga (d, +d, h + d) = y-up (d, h + d, -d).
    (folder / "quad.obj").write_text(
        "mtllib quad.mtl\n"
        f"v {d} {h + d} {-d}\nv {d} {h + d} {d}\nv {d} {h - d} {d}\nv {d} {h - d} {-d}\n"
        "vt 0 1\nvt 1 1\nvt 1 0\nvt 0 0\n"
        "usemtl paint\nf 1/1 4/4 3/3\nf 1/1 3/3 2/2\n"
    )
    return folder / "quad.obj"


def test_obj_with_mtl_and_texture_loads_upright(tmp_path, camera, pattern):
    scene, ids = load_mesh_scene(_write_obj_quad(tmp_path, pattern))
    view = MeshRenderer(scene, camera, shading=False).render(Pose(0.0, 0.0, 0.0, 1.5))
    assert ids == {}
    assert np.abs(view.rgb.astype(int) - pattern).max() <= 1


@pytest.mark.parametrize(
    ("name", "content", "expected"),
    [
        ("missing.glb", None, "no such mesh file"),
        ("garbage.glb", b"\x00not a glb at all" * 10, "cannot read a triangle mesh"),
        ("garbage.obj", b"this is not\nan obj file\n", "cannot read a triangle mesh"),
        ("scene.stl", b"solid nothing\nendsolid\n", "unsupported mesh format"),  # PLY is read: tests/test_ply.py
    ],
)
def test_bad_mesh_files_are_one_line_input_errors(tmp_path, name, content, expected):
    if content is not None:
        (tmp_path / name).write_bytes(content)
    with pytest.raises(InputError) as error:
        load_mesh_scene(tmp_path / name)
    message = str(error.value)
    assert name in message and expected in message and "\n" not in message


@pytest.mark.parametrize(
    ("sidecar", "expected"),
    [
        ("{not json", "cannot read the semantic sidecar as JSON"),
        ('{"geometries": []}', "expected"),
        ('{"geometries": {"floor": {"category": "nope"}}}', "needs 'semantic_id' or a 'category'"),
        ('{"geometries": {"floor": {"semantic_id": "two"}}}', "must be integers"),
    ],
)
def test_bad_sidecars_are_input_errors_naming_the_sidecar(tmp_path, sidecar, expected):
    box_room(crates=False).export(tmp_path / "room.glb")
    (tmp_path / "room.semantic.json").write_text(sidecar)
    with pytest.raises(InputError, match=expected) as error:
        load_mesh_scene(tmp_path / "room.glb")
    assert "room.semantic.json" in str(error.value)
