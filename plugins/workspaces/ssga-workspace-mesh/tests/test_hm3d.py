"""HM3D's semantic annotations (a vertex-coloured mesh and its table) as per-pixel ids."""

from __future__ import annotations

import pickle
import shutil

import numpy as np
import pytest
import trimesh

from ssga_core import Camera, InputError, Pose
from ssga_workspace_mesh.basisu import join_glb, split_glb
from ssga_workspace_mesh.hm3d import _majority_corner, read_semantic_table, semantic_files
from ssga_workspace_mesh.loading import Z_UP_TO_Y_UP, load_mesh_scene
from ssga_workspace_mesh.meshdata import UNANNOTATED
from ssga_workspace_mesh.plugin import MeshConfig, MeshWorkspaceSource
from ssga_workspace_mesh.renderer import MeshRenderer
from ssga_workspace_mesh.scenes import CRATES, box_room

# Object id, colour, category of each part of box_room; crate_b's colour is not in the
# table (unannotated) and the ceiling is left out of the semantic mesh.
OBJECTS = {
    "wall_east": (11, 0x1F77B4, "wall"),
    "wall_west": (12, 0xFF7F0E, "wall"),
    "wall_north": (13, 0x2CA02C, "wall"),
    "wall_south": (14, 0xD62728, "wall"),
    "floor": (15, 0x9467BD, "floor"),
    "crate_a": (16, 0x8C564B, "crate, wooden"),
}
UNLISTED = {"crate_b": 0xE377C2}
CATEGORIES = {"crate, wooden": 0, "floor": 1, "wall": 2}  # the names sorted
TABLE = "HM3D Semantic Annotations\n" + "".join(f'{i},{c:06X},"{n}",{i % 2}\n' for i, c, n in OBJECTS.values())


def _semantic_mesh() -> trimesh.Scene:
    """box_room without its ceiling, every vertex coloured with its object's colour."""
    room = box_room()
    colours = {name: colour for name, (_, colour, _) in OBJECTS.items()} | UNLISTED
    scene = trimesh.Scene()
    for name, colour in colours.items():
        part = room.geometry[name].copy()
        part.visual = trimesh.visual.ColorVisuals(part, vertex_colors=[(colour >> 16) & 255, (colour >> 8) & 255, colour & 255, 255])
        scene.add_geometry(part, geom_name=name)
    return scene


def _y_up_glb(scene: trimesh.Scene) -> bytes:
    exported = scene.copy()
    exported.apply_transform(Z_UP_TO_Y_UP)
    return exported.export(file_type="glb")


def _as_blender_writes(glb: bytes) -> bytes:
    """The same GLB with COLOR_0 stored as normalised 16-bit integers and a material on every
    primitive, as Blender writes them (trimesh then keeps the colours as they are stored)."""
    gltf, binary = split_glb(glb)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    gltf["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0]}}]
    for mesh in gltf["meshes"]:
        for primitive in mesh["primitives"]:
            primitive["material"] = 0
            accessor = gltf["accessors"][primitive["attributes"]["COLOR_0"]]
            view = gltf["bufferViews"][accessor["bufferView"]]
            start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
            width = {"VEC3": 3, "VEC4": 4}[accessor["type"]]
            rgba8 = np.frombuffer(binary, np.uint8, accessor["count"] * width, start)
            wide = (rgba8.astype(np.uint16) * 257).tobytes()
            gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(wide)})
            binary += wide + b"\0" * (-len(wide) % 4)
            accessor.update(bufferView=len(gltf["bufferViews"]) - 1, byteOffset=0, componentType=5123, normalized=True)
    gltf["buffers"][0]["byteLength"] = len(binary)
    return join_glb(gltf, binary)


@pytest.fixture(params=["8-bit", "16-bit-with-material"])
def scene_dir(request, tmp_path):
    """An HM3D-style folder: room.basis.glb, room.semantic.glb and room.semantic.txt, y up."""
    (tmp_path / "room.basis.glb").write_bytes(_y_up_glb(box_room()))
    semantic = _y_up_glb(_semantic_mesh())
    (tmp_path / "room.semantic.glb").write_bytes(_as_blender_writes(semantic) if request.param != "8-bit" else semantic)
    (tmp_path / "room.semantic.txt").write_text(TABLE)
    return tmp_path


@pytest.fixture(scope="module")
def camera():
    return Camera(width=128, height=128, hfov_deg=90.0)


def _pixel(camera: Camera, pose: Pose, point: tuple[float, float, float]) -> tuple[int, int]:
    uv, _ = camera.project(pose.to_camera(np.array([point])))
    u, v = np.rint(uv[0]).astype(int)
    return v, u


def test_views_carry_hm3d_object_and_category_ids(scene_dir, camera):
    scene, _ = load_mesh_scene(scene_dir / "room.basis.glb")
    renderer = MeshRenderer(scene, camera)
    pose = Pose(0.0, 0.0, 0.0, 1.5)  # looking along +x, at the east wall; crate_a ahead and to the left
    view = renderer.render(pose)
    assert (view.instance[64, 64], view.semantic[64, 64]) == (11, CATEGORIES["wall"])
    (x, y), _ = CRATES["crate_a"]
    crate = _pixel(camera, pose, (x - 0.3, y, 1.0))  # on its face towards the camera
    assert (view.instance[crate], view.semantic[crate]) == (16, CATEGORIES["crate, wooden"])
    assert (view.instance[0, 64], view.semantic[0, 64]) == (UNANNOTATED, -1), "the ceiling is not in the semantic mesh"
    assert view.valid_depth().all()

    behind = Pose(0.0, 0.0, np.pi, 1.5)  # looking along -x: crate_b, whose colour is not in the table
    (x, y), _ = CRATES["crate_b"]
    view = renderer.render(behind)
    crate = _pixel(camera, behind, (x + 0.4, y, 1.0))
    assert view.depth[crate] == pytest.approx(-x - 0.4, abs=1e-3), "the crate is seen, ..."
    assert (view.instance[crate], view.semantic[crate]) == (UNANNOTATED, -1), "... and unannotated"
    assert (view.instance[64, 64], view.semantic[64, 64]) == (12, CATEGORIES["wall"])
    assert set(np.unique(view.instance)) <= {UNANNOTATED, 11, 12, 13, 14, 15, 16}


def test_the_semantic_mesh_is_not_seen_in_rgb_or_depth(scene_dir, tmp_path_factory, camera):
    plain_dir = tmp_path_factory.mktemp("plain")
    shutil.copy(scene_dir / "room.basis.glb", plain_dir / "room.basis.glb")
    with_labels = MeshRenderer(load_mesh_scene(scene_dir / "room.basis.glb")[0], camera)
    without = MeshRenderer(load_mesh_scene(plain_dir / "room.basis.glb")[0], camera)
    for pose in (Pose(0.5, -0.5, 0.3, 1.5), Pose(-1.0, 1.0, 2.5, 1.2)):
        a, b = with_labels.render(pose), without.render(pose)
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.depth, b.depth)
        assert not np.array_equal(a.instance, b.instance)


def test_a_mesh_workspace_opened_on_the_scene_carries_them(scene_dir):
    workspace = MeshWorkspaceSource(MeshConfig(path=scene_dir / "room.basis.glb", width=64, height=64)).open()
    # The floor plan is derived from the visible mesh alone: the room's 8 x 6 m less the crates and clearance.
    assert 30.0 < workspace.floor_plan.free.area < 48.0
    view = workspace.render(Pose(0.0, 0.0, 0.0, 1.5))
    assert (view.instance[32, 32], view.semantic[32, 32]) == (11, CATEGORIES["wall"])


def test_labels_survive_the_trip_to_a_worker_process(scene_dir, camera):
    renderer = MeshRenderer(load_mesh_scene(scene_dir / "room.basis.glb")[0], camera)
    copy = pickle.loads(pickle.dumps(renderer))  # what render_many sends its workers
    pose = Pose(0.3, 0.2, 0.4, 1.5)
    np.testing.assert_array_equal(copy.render(pose).instance, renderer.render(pose).instance)
    np.testing.assert_array_equal(copy.render(pose).semantic, renderer.render(pose).semantic)


def test_the_table_is_read_as_habitat_reads_it(tmp_path):
    path = tmp_path / "x.semantic.txt"
    path.write_text('HM3D Semantic Annotations\n3,00FF00,"sofa",1\n\n1,ff0000,"kitchen cabinet, upper",0\n4,00FF00,"rug",1\n')
    table = read_semantic_table(path)
    assert table.ids.tolist() == [3, 1, 4] and table.colours.tolist() == [0x00FF00, 0xFF0000, 0x00FF00]
    assert table.categories == {"kitchen cabinet, upper": 0, "rug": 1, "sofa": 2}
    assert table.regions.tolist() == [1, 0, 1]
    semantic, instance = table.lookup(np.array([0xFF0000, 0x0000FF, 0x00FF00]))
    assert semantic.tolist() == [0, -1, 2] and instance.tolist() == [1, UNANNOTATED, 3], "a colour listed twice: the first"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('1,FF0000,"wall",0\n', "first line should contain"),
        ('HM3D Semantic Annotations\n1,FF0000,"wall"\n', 'x.semantic.txt:2: expected id,RRGGBB,"category",region'),
        ('HM3D Semantic Annotations\n1,FF0000,"wall",0\n2,red,"door",0\n', "x.semantic.txt:3: expected"),
    ],
)
def test_a_bad_table_is_a_one_line_error_naming_it(tmp_path, text, expected):
    path = tmp_path / "x.semantic.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=expected) as error:
        read_semantic_table(path)
    assert "x.semantic.txt" in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize("missing", ["room.semantic.txt", "room.semantic.glb"])
def test_half_of_the_annotations_is_an_error_naming_the_other_half(scene_dir, missing):
    (scene_dir / missing).unlink()
    with pytest.raises(InputError, match=f"{missing}: missing"):
        load_mesh_scene(scene_dir / "room.basis.glb")


def test_semantic_files_sit_beside_the_scene():
    assert semantic_files("hm3d/00800-TEEsavR23oF/TEEsavR23oF.basis.glb") == (
        semantic_files("hm3d/00800-TEEsavR23oF/TEEsavR23oF.glb")
    )
    glb, txt = semantic_files("hm3d/00800-TEEsavR23oF/TEEsavR23oF.basis.glb")
    assert (glb.name, txt.name) == ("TEEsavR23oF.semantic.glb", "TEEsavR23oF.semantic.txt")


def test_a_face_takes_the_object_two_of_its_corners_share():
    corners = np.array([[5, 5, 7], [7, 5, 5], [5, 7, 5], [1, 2, 3], [4, 4, 4]])
    chosen = corners[np.arange(len(corners)), _majority_corner(corners)]
    assert chosen.tolist() == [5, 5, 5, 1, 4]
