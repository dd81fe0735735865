"""PLY scans (and vertex-coloured OBJ and GLB) through the mesh workspace: read, rendered, planned, refused.

Every PLY here is written by :func:`write_ply`, a stand-in for a scanner's or MeshLab's
export: ASCII or binary of either byte order, colours as bytes or floats, faces as
triangles or polygons under either name exporters use, texture coordinates per face or
per vertex.
"""

from __future__ import annotations

import json
import math
import pickle
import struct
from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh
from PIL import Image
from shapely import affinity
from typer.testing import CliRunner

from ssga_core import Camera, InputError, Pose
from ssga_core.cli import app_with_plugin_commands
from ssga_workspace_mesh.floorplan import floor_plan_from_mesh
from ssga_workspace_mesh.loading import load_mesh_scene
from ssga_workspace_mesh.plugin import MeshConfig, MeshWorkspaceSource
from ssga_workspace_mesh.renderer import MeshRenderer
from ssga_workspace_mesh.scenes import box_room

STRUCT = {"float": "f", "double": "d", "uchar": "B", "ushort": "H", "int": "i", "uint": "I"}
SMALL = Camera(width=64, height=64, hfov_deg=90.0)
AHEAD = Pose(0.0, 0.0, 0.0, 1.5)
"""A camera at the origin looking along +x: the quad of :func:`quad` fills its view."""


def write_ply(
    path: Path,
    vertices: np.ndarray,
    faces: list[list[int]],
    *,
    fmt: str = "binary_little_endian",
    colours: np.ndarray | None = None,
    colour_type: str = "uchar",
    alpha: bool = False,
    index_name: str = "vertex_indices",
    vertex_uv: np.ndarray | None = None,
    face_uv: list[list[float]] | None = None,
    texnumber: list[int] | None = None,
    textures: tuple[str, ...] = (),
) -> Path:
    """A PLY file as exporters write them; ``colours`` are floats in [0, 1], written as ``colour_type``."""
    vprops = [("float", n) for n in "xyz"]
    columns = [np.asarray(vertices, dtype=np.float64)]
    if colours is not None:
        names = ["red", "green", "blue", "alpha"] if alpha else ["red", "green", "blue"]
        rgba = np.column_stack([colours, np.ones(len(colours))])[:, : len(names)]
        scale = {"uchar": 255.0, "ushort": 65535.0}.get(colour_type, 1.0)
        vprops += [(colour_type, n) for n in names]
        columns.append(np.rint(rgba * scale) if scale != 1.0 else rgba)
    if vertex_uv is not None:
        vprops += [("float", "s"), ("float", "t")]
        columns.append(np.asarray(vertex_uv, dtype=np.float64))
    table = np.column_stack(columns)
    header = ["ply", f"format {fmt} 1.0", "comment written by the ssga tests", *(f"comment TextureFile {t}" for t in textures)]
    header += [f"element vertex {len(vertices)}", *(f"property {t} {n}" for t, n in vprops)]
    header += [f"element face {len(faces)}", f"property list uchar int {index_name}"]
    if face_uv is not None:
        header.append("property list uchar float texcoord")
    if texnumber is not None:
        header.append("property int texnumber")
    header.append("end_header")
    head = ("\n".join(header) + "\n").encode()
    if fmt == "ascii":
        rows = [" ".join(f"{v:g}" if t in ("float", "double") else str(int(v)) for (t, _), v in zip(vprops, row, strict=True)) for row in table]
        for k, face in enumerate(faces):
            row = [str(len(face)), *map(str, face)]
            if face_uv is not None:
                row += [str(len(face_uv[k])), *(f"{u:g}" for u in face_uv[k])]
            if texnumber is not None:
                row.append(str(texnumber[k]))
            rows.append(" ".join(row))
        path.write_bytes(head + ("\n".join(rows) + "\n").encode())
        return path
    order = "<" if fmt == "binary_little_endian" else ">"
    vertex = struct.Struct(order + "".join(STRUCT[t] for t, _ in vprops))
    body = [vertex.pack(*(int(v) if t not in ("float", "double") else v for (t, _), v in zip(vprops, row, strict=True))) for row in table]
    for k, face in enumerate(faces):
        body.append(struct.pack(f"{order}B{len(face)}i", len(face), *face))
        if face_uv is not None:
            body.append(struct.pack(f"{order}B{len(face_uv[k])}f", len(face_uv[k]), *face_uv[k]))
        if texnumber is not None:
            body.append(struct.pack(f"{order}i", texnumber[k]))
    path.write_bytes(head + b"".join(body))
    return path


def quad(d: float = 2.0, h: float = 1.5) -> np.ndarray:
    """Top-left, top-right, bottom-right, bottom-left corners (z up) of a square at x = d that fills :data:`AHEAD`'s view."""
    return np.array([[d, d, h + d], [d, -d, h + d], [d, -d, h - d], [d, d, h - d]])


RED_LEFT_BLUE_RIGHT = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, 0, 1.0], [1.0, 0, 0]])
UV = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
"""trimesh's (and PLY's) uv of the quad's corners: the image upright, origin at its bottom-left."""


@pytest.mark.parametrize(
    ("fmt", "colour_type", "alpha", "index_name", "as_quad"),
    [
        ("ascii", "uchar", False, "vertex_indices", True),
        ("ascii", "float", True, "vertex_index", False),
        ("binary_little_endian", "float", False, "vertex_index", True),
        ("binary_little_endian", "uchar", True, "vertex_indices", False),
        ("binary_big_endian", "uchar", True, "vertex_indices", True),
        ("binary_big_endian", "ushort", False, "vertex_index", True),
    ],
)
def test_vertex_colours_are_read_and_interpolated_across_faces(tmp_path, fmt, colour_type, alpha, index_name, as_quad):
    # A triangle behind the camera makes the binary files mix quads and triangles (what trimesh cannot read).
    vertices = np.vstack([quad(), [[-3, 0, 0], [-3, 1, 0], [-3, 0, 1]]])
    colours = np.vstack([RED_LEFT_BLUE_RIGHT, np.full((3, 3), 0.5)])
    faces = [[0, 1, 2, 3], [4, 5, 6]] if as_quad else [[0, 1, 2], [0, 2, 3], [4, 5, 6]]
    path = write_ply(tmp_path / "scan.ply", vertices, faces, fmt=fmt, colours=colours, colour_type=colour_type, alpha=alpha, index_name=index_name)
    scene, ids = load_mesh_scene(path, up_axis="z")
    assert ids == {} and list(scene.geometry) == ["scan"]
    mesh = scene.geometry["scan"]
    assert len(mesh.faces) == 3 and np.allclose(mesh.vertices, vertices)
    view = MeshRenderer(scene, SMALL, shading=False).render(AHEAD)
    rgb = view.rgb.astype(int)
    assert view.valid_depth().all() and np.allclose(view.depth, 2.0, atol=1e-4)
    # Red at the left edge, blue at the right, and in between a blend: the quad's two triangles agree.
    row = rgb[32]
    assert row[0, 0] > 245 and row[0, 2] < 10 and row[-1, 2] > 245 and row[-1, 0] < 10
    assert abs(row[32, 0] - 127) <= 6 and abs(row[32, 2] - 127) <= 6 and row[32, 1] == 0
    assert np.all(np.diff(row[:, 0]) <= 0) and np.all(np.diff(row[:, 2]) >= 0)
    assert np.abs(rgb[..., 0] + rgb[..., 2] - 255).max() <= 2
    assert np.abs(rgb - rgb[32]).max() <= 1, "the colour does not change down a column"


def test_a_texture_named_by_the_file_maps_upright(tmp_path, camera, pattern):
    Image.fromarray(pattern).save(tmp_path / "paint.png")
    per_face = write_ply(tmp_path / "meshlab.ply", quad(), [[0, 1, 2, 3]], face_uv=[list(UV.ravel())], textures=("paint.png",))
    per_vertex = write_ply(tmp_path / "vertex.ply", quad(), [[0, 3, 2], [0, 2, 1]], fmt="ascii", vertex_uv=UV, textures=("paint.png",))
    for path in (per_face, per_vertex):
        scene, _ = load_mesh_scene(path, up_axis="z")
        view = MeshRenderer(scene, camera, shading=False).render(AHEAD)
        assert np.abs(view.rgb.astype(int) - pattern).max() <= 1, path.name


def test_several_textures_and_a_seam(tmp_path, camera, pattern):
    """MeshLab's texnumber picks each face's texture; faces disagreeing on a shared corner's uv split it."""
    Image.fromarray(pattern).save(tmp_path / "a.png")
    Image.fromarray(255 - pattern).save(tmp_path / "b.png")
    uv = UV.ravel().tolist()
    upper = [*uv[0:2], *uv[2:4], *uv[4:6]]  # corners 0, 1, 2
    lower = [*uv[0:2], *uv[4:6], *uv[6:8]]  # corners 0, 2, 3
    path = write_ply(
        tmp_path / "two.ply", quad(), [[0, 1, 2], [0, 2, 3]], face_uv=[upper, lower], texnumber=[0, 1], textures=("a.png", "b.png")
    )
    scene, _ = load_mesh_scene(path, up_axis="z")
    assert sorted(scene.geometry) == ["two_0", "two_1"]
    rgb = MeshRenderer(scene, camera, shading=False).render(AHEAD).rgb.astype(int)
    v, u = np.mgrid[0:256, 0:256]
    above, below = u > v + 2, u < v - 2  # the diagonal from the top-left to the bottom-right corner
    assert np.abs(rgb[above] - pattern[above]).max() <= 1
    assert np.abs(rgb[below] - (255 - pattern[below])).max() <= 1


def glb_with_colour_and_material(path: Path, vertices: np.ndarray, faces: np.ndarray, colours: np.ndarray) -> Path:
    """One primitive with COLOR_0 and a material (white baseColorFactor): trimesh keeps such colours aside."""
    blobs = [vertices.astype(np.float32).tobytes(), np.column_stack([colours, np.ones(len(colours))]).astype(np.float32).tobytes()]
    blobs.append(faces.astype(np.uint32).tobytes())
    offsets = np.cumsum([0, *map(len, blobs)])
    views = [{"buffer": 0, "byteOffset": int(o), "byteLength": len(b)} for o, b in zip(offsets, blobs, strict=False)]
    gltf = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "COLOR_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1]}}],
        "buffers": [{"byteLength": int(offsets[-1])}], "bufferViews": views,
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(vertices), "type": "VEC3",
             "min": vertices.min(axis=0).tolist(), "max": vertices.max(axis=0).tolist()},
            {"bufferView": 1, "componentType": 5126, "count": len(vertices), "type": "VEC4"},
            {"bufferView": 2, "componentType": 5125, "count": faces.size, "type": "SCALAR"},
        ],
    }  # fmt: skip
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    binary = b"".join(blobs)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
    return path


def test_vertex_coloured_obj_and_glb_interpolate_too(tmp_path):
    lines = [f"v {x:g} {y:g} {z:g} {r:g} {g:g} {b:g}" for (x, y, z), (r, g, b) in zip(quad(), RED_LEFT_BLUE_RIGHT, strict=True)]
    (tmp_path / "scan.obj").write_text("\n".join(lines) + "\nf 1 2 3\nf 1 3 4\n")
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    plain = trimesh.Trimesh(quad(), faces, vertex_colors=np.rint(RED_LEFT_BLUE_RIGHT * 255).astype(np.uint8), process=False)
    trimesh.Scene(plain).export(tmp_path / "plain.glb")
    glb_with_colour_and_material(tmp_path / "material.glb", quad(), faces, RED_LEFT_BLUE_RIGHT)
    for name in ("scan.obj", "plain.glb", "material.glb"):
        scene, _ = load_mesh_scene(tmp_path / name, up_axis="z")
        row = MeshRenderer(scene, SMALL, shading=False).render(AHEAD).rgb[32].astype(int)
        assert row[0, 0] > 245 and row[-1, 2] > 245, name
        assert abs(row[32, 0] - 127) <= 6 and abs(row[32, 2] - 127) <= 6, name


def room_as_ply(scene: trimesh.Scene, path: Path, transform: np.ndarray | None = None, fmt: str = "binary_little_endian") -> Path:
    """A scene written as one vertex-coloured mesh, as a scanner exports it: every face's colour on its corners."""
    meshes = scene.dump()
    corners = np.concatenate([m.vertices[m.faces].reshape(-1, 3) for m in meshes])
    colours = np.concatenate([np.repeat(m.visual.face_colors[:, :3] / 255.0, 3, axis=0) for m in meshes])
    vertices = corners if transform is None else trimesh.transform_points(corners, transform)
    return write_ply(path, vertices, np.arange(len(corners)).reshape(-1, 3).tolist(), fmt=fmt, colours=colours)


def test_a_tilted_box_room_levels_and_plans_as_the_room(tmp_path, capsys):
    rng = np.random.default_rng(7)
    turn = trimesh.transformations.random_rotation_matrix(rng.random(3))
    turn[:3, 3] = rng.uniform(-5, 5, 3)
    path = room_as_ply(box_room(), tmp_path / "room.ply", turn)
    workspace = MeshWorkspaceSource(MeshConfig(path=path, up_axis="auto", width=64, height=64)).open()
    assert "found up" in capsys.readouterr().err
    assert workspace.camera_height == 1.5
    # The file's frame back to the room's, then levelled: a turn about z and a shift in the plane.
    moved = workspace.levelling.transform @ turn
    assert abs(moved[2, 2] - 1.0) < 1e-4 and abs(moved[2, 3]) < 0.01, "levelled, floor at z = 0"
    expected = floor_plan_from_mesh(box_room())
    a, b, c, d = moved[0, 0], moved[0, 1], moved[1, 0], moved[1, 1]
    expected_free = affinity.affine_transform(expected.free, [a, b, c, d, moved[0, 3], moved[1, 3]])
    free = workspace.floor_plan.free
    assert free.symmetric_difference(expected_free).area < 0.05 * expected_free.area
    # And the room renders in its colours from inside it.
    x, y = shapely.get_coordinates(free.representative_point())[0]
    view = workspace.render(Pose(x, y, 0.0, workspace.camera_height))
    assert view.valid_depth().all() and len(np.unique(view.rgb.reshape(-1, 3), axis=0)) > 3


def low_scan() -> trimesh.Scene:
    """A room scanned as ScanNet's are: no ceiling, walls ending at 1.4 m (its crates stand higher)."""
    scene = box_room(height=1.4)
    scene.delete_geometry("ceiling")
    return scene


def test_a_scan_ending_below_the_camera_is_planned_lower_and_says_so(tmp_path, capsys):
    path = room_as_ply(low_scan(), tmp_path / "scannet.ply")
    workspace = MeshWorkspaceSource(MeshConfig(path=path, up_axis="z", width=64, height=64)).open()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no geometry at camera_height 1.5 m" in err[0] and "walls end at about 1.4" in err[0]
    assert 1.0 < workspace.camera_height < 1.2 and f"views are taken at {workspace.camera_height:g} m" in err[0]
    inside = (8 - 2 * 0.25) * (6 - 2 * 0.25)
    assert 0.8 * inside < workspace.floor_plan.free.area < inside
    view = workspace.render(Pose(0.0, 0.0, 0.0, workspace.camera_height))
    assert view.valid_depth().mean() > 0.5


def test_a_scan_with_nothing_at_any_height_names_the_cause(tmp_path):
    bare = box_room(crates=False)
    for name in list(bare.geometry):
        if name != "floor":
            bare.delete_geometry(name)
    path = room_as_ply(bare, tmp_path / "floor.ply")
    with pytest.raises(InputError) as raised:
        MeshWorkspaceSource(MeshConfig(path=path, up_axis="z")).open()
    message = str(raised.value)
    assert "\n" not in message and "floor.ply" in message and "no geometry at camera height 1.5 m" in message
    assert "up_axis" not in message
    assert str(pickle.loads(pickle.dumps(raised.value))) == message, "it crosses from worker processes intact"


def ply_bytes(body: bytes, vertex: str = "property float x\nproperty float y\nproperty float z\n", fmt: str = "ascii", faces: int = 1) -> bytes:
    return f"ply\nformat {fmt} 1.0\nelement vertex 3\n{vertex}element face {faces}\nproperty list uchar int vertex_indices\nend_header\n".encode() + body


TRIANGLE = b"0 0 0\n1 0 0\n0 1 0\n"
BINARY_TRIANGLE = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0) + struct.pack("<B3i", 3, 0, 1, 2)


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"plyx\nformat ascii 1.0\nend_header\n", "not a PLY file (expected its first line to be 'ply')"),
        (b"ply\nformat ascii 1.0\nelement vertex 3\n", "expected an 'end_header' line"),
        (b"ply\nformat utf8 1.0\nend_header\n", "expected 'format ascii|binary_little_endian|binary_big_endian 1.0'"),
        (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", "a property before any element"),
        (ply_bytes(TRIANGLE + b"3 0 1 2\n", vertex="property float x\nproperty float y\nproperty half z\n"), "unknown property type 'half'"),
        (ply_bytes(TRIANGLE + b"3 0 1 7\n"), "face 0 refers to vertex 7, but the file has 3 vertices (expected indices 0 to 2)"),
        (ply_bytes(TRIANGLE + b"3 0 1 2\n3 0 1", faces=2), "truncated: the file ends in 'face' record 1 of the 2"),
        (ply_bytes(TRIANGLE + b"3 0 one 2\n"), "expected numbers separated by spaces after the header, found 'one'"),
        (ply_bytes(BINARY_TRIANGLE[:-6], fmt="binary_little_endian"), "truncated: the file ends in 'face' record 0"),
        (ply_bytes(BINARY_TRIANGLE[:20], fmt="binary_little_endian"), "truncated: the header declares 3 'vertex' records, the rest of the file has room for at most 1"),
        (ply_bytes(TRIANGLE, faces=0), "no faces (expected a 'face' element"),
        (ply_bytes(TRIANGLE + b"3 0 1 2\n", faces=10**11), "the header declares 100000000000 'face' records, the rest of the file has room"),
        (ply_bytes(b"0 0 nan\n1 0 0\n0 1 0\n3 0 1 2\n"), "vertex 0 is at (0, 0, nan) (expected finite coordinates)"),
    ],
)
def test_bad_ply_files_are_one_line_input_errors(tmp_path, content, expected):
    (tmp_path / "scan.ply").write_bytes(content)
    with pytest.raises(InputError) as raised:
        load_mesh_scene(tmp_path / "scan.ply", up_axis="z")
    message = str(raised.value)
    assert message.startswith(str(tmp_path / "scan.ply") + ": ") and expected in message and "\n" not in message


def test_a_missing_texture_is_an_input_error(tmp_path):
    path = write_ply(tmp_path / "scan.ply", quad(), [[0, 1, 2, 3]], vertex_uv=UV, textures=("gone.png",))
    with pytest.raises(InputError, match=r"scan.ply: its texture 'gone.png' \(comment TextureFile\) is missing"):
        load_mesh_scene(path, up_axis="z")


def test_the_config_names_ply(tmp_path):
    assert ".ply" in MeshConfig.model_fields["path"].description
    problems = MeshWorkspaceSource.missing(MeshConfig(path=tmp_path / "nowhere.ply"))
    assert problems == [f"path: no such mesh file {tmp_path / 'nowhere.ply'} (expected a .glb, .gltf, .obj or .ply file)"]


def test_validation_opens_the_mesh_far_enough_to_know_it_can_be_read(tmp_path):
    """`ssga config validate` refuses what `ssga run` would stop on after loading, in one line naming the file."""
    good = write_ply(tmp_path / "good.ply", quad(), [[0, 1, 2, 3]])
    assert MeshWorkspaceSource.missing(MeshConfig(path=good)) == []
    data = good.read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[: len(data) - 10])
    (tmp_path / "cloud.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n")
    (tmp_path / "text.ply").write_bytes(b"solid cube\n")
    (tmp_path / "fake.glb").write_bytes(b"not a glb at all")
    (tmp_path / "cut.glb").write_bytes(b"glTF" + (2).to_bytes(4, "little") + (1000).to_bytes(4, "little") + b"JSON")
    expected = {
        "cut.ply": "truncated",
        "cloud.ply": "no faces",
        "text.ply": "not a PLY file",
        "fake.glb": "not a binary glTF file",
        "cut.glb": "truncated: its header declares 1000 bytes",
    }
    for name, words in expected.items():
        problems = MeshWorkspaceSource.missing(MeshConfig(path=tmp_path / name))
        assert len(problems) == 1 and problems[0].startswith(f"path: {tmp_path / name}: ") and words in problems[0], problems


@pytest.mark.slow
def test_workspace_build_from_a_tilted_low_ply_scan(tmp_path, monkeypatch):
    """A ScanNet-like scan end to end: PLY, any orientation, walls below the camera."""
    scene = low_scan()
    turn = trimesh.transformations.rotation_matrix(math.radians(30.0), [1.0, -0.5, 0.3])
    room_as_ply(scene, tmp_path / "scene0000_00_vh_clean.ply", turn)
    monkeypatch.chdir(tmp_path)
    args = ["workspace", "build", "--source", "mesh", "-o", "path=scene0000_00_vh_clean.ply", "-o", "up_axis=auto"]
    args += ["-o", "width=48", "-o", "height=48", "--cells", "4", "--test-per-class", "1"]
    result = CliRunner().invoke(app_with_plugin_commands(), args)
    assert result.exit_code == 0, result.output
    assert "found up" in result.output and "no geometry at camera_height 1.5 m" in result.output
    assert "48 classes" in result.output
    folder = next((tmp_path / "runs" / "workspaces").glob("scene0000_00_vh_clean-*"))
    assert json.loads((folder / "dataset.json").read_text())["source"]["up_axis"] == "auto"
    heights = {sample["height"] for sample in json.loads((folder / "plan.json").read_text())["samples"]}
    assert len(heights) == 1 and 1.0 < heights.pop() < 1.2, "every view is taken at the lowered height"
