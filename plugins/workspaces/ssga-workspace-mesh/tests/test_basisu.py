"""Basis Universal textures (KTX2 and .basis, as Habitat's scenes store them) decoded on load."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ssga_core import Camera, InputError, Pose
from ssga_workspace_mesh.basisu import join_glb, split_glb
from ssga_workspace_mesh.loading import load_mesh_scene
from ssga_workspace_mesh.renderer import MeshRenderer
from ssga_workspace_mesh.scenes import textured_quad

DATA = Path(__file__).parent / "data"
QUADRANTS = {"top-left": (230, 40, 40), "top-right": (40, 200, 40), "bottom-left": (40, 60, 220), "bottom-right": (240, 220, 40)}
"""The colours of data/quadrants*.basis (see data/README.md)."""

POSE = Pose(0.0, 0.0, 0.0, 1.5)


def _quad_scene(image: np.ndarray, base_colour: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)) -> trimesh.Scene:
    """A textured quad filling the 90-degree view of a camera at the origin looking along +x (z up)."""
    d, h = 2.0, 1.5
    quad = textured_quad(np.array([[d, d, h + d], [d, -d, h + d], [d, -d, h - d], [d, d, h - d]]), image)
    quad.visual.material.baseColorFactor = np.array(base_colour)
    scene = trimesh.Scene()
    scene.add_geometry(quad, geom_name="quad")
    return scene


def _with_basis_image(glb: bytes, payload: bytes, mime: str, extension: str) -> bytes:
    """``glb`` (one textured material) with its image replaced by ``payload``, referenced as
    Habitat's files do: through ``extension``'s ``source``, not the texture's own."""
    gltf, binary = split_glb(glb)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(payload)})
    binary += payload
    gltf["buffers"][0]["byteLength"] = len(binary)
    gltf["images"] = [{"bufferView": len(gltf["bufferViews"]) - 1, "mimeType": mime}]
    for texture in gltf["textures"]:
        texture["extensions"] = {extension: {"source": texture.pop("source")}}
    gltf["extensionsUsed"] = gltf["extensionsRequired"] = [extension]
    return join_glb(gltf, binary)


def _ktx2(image: np.ndarray, codec: str) -> bytes:
    alktx2 = pytest.importorskip("alktx2")
    rgba = np.dstack([image, np.full(image.shape[:2], 255, np.uint8)])
    return alktx2.encode_raw_rgba_to_ktx2(rgba.tobytes(), image.shape[1], image.shape[0], has_alpha=False, codec=codec, threads=1)


def _render(path: Path) -> np.ndarray:
    scene, _ = load_mesh_scene(path, up_axis="z")
    return MeshRenderer(scene, Camera(width=64, height=64, hfov_deg=90.0), shading=False).render(POSE).rgb


@pytest.mark.parametrize("codec", ["etc1s", "uastc"])
def test_a_ktx2_texture_renders_as_its_image(tmp_path, pattern, codec):
    # A grey base colour factor: a loader that drops the texture renders flat grey.
    scene = _quad_scene(pattern, base_colour=(0.5, 0.5, 0.5, 1.0))
    path = tmp_path / "quad.basis.glb"
    path.write_bytes(_with_basis_image(scene.export(file_type="glb"), _ktx2(pattern, codec), "image/ktx2", "KHR_texture_basisu"))
    assert trimesh.load(path, force="scene").geometry["quad"].visual.material.baseColorTexture is None, "trimesh alone drops it"

    loaded, _ = load_mesh_scene(path, up_axis="z")
    view = MeshRenderer(loaded, Camera(width=256, height=256, hfov_deg=90.0), shading=False).render(POSE)
    expected = pattern.astype(float) * 0.5  # texture x baseColorFactor, each pixel on one texel centre
    error = np.abs(view.rgb.astype(float) - expected)
    # Basis Universal is lossy (ETC1S more than UASTC); the flat base colour would be ~40 off on average.
    assert error.mean() < (6.0 if codec == "etc1s" else 2.0)
    assert view.rgb[:40, :60].mean() > 120 and view.rgb[60:, 80:].std() > 20, "the marker top-left, the ramp elsewhere"


@pytest.mark.parametrize("name", ["quadrants.basis", "quadrants_y_flipped.basis"])
def test_a_google_basis_texture_renders_upright(tmp_path, name):
    path = tmp_path / "quad.basis.glb"
    glb = _quad_scene(np.zeros((16, 16, 3), np.uint8)).export(file_type="glb")
    path.write_bytes(_with_basis_image(glb, (DATA / name).read_bytes(), "image/x-basis", "GOOGLE_texture_basis"))
    rgb = _render(path)
    # Quadrant centres, away from the bilinear blend across the quadrants' borders.
    samples = {"top-left": rgb[16, 16], "top-right": rgb[16, 48], "bottom-left": rgb[48, 16], "bottom-right": rgb[48, 48]}
    for where, colour in QUADRANTS.items():
        np.testing.assert_allclose(samples[where], colour, atol=12, err_msg=where)


def test_a_gltf_with_a_ktx2_file_beside_it(tmp_path, pattern):
    # The .gltf flavour: JSON, with the image as a file its uri names.
    scene = _quad_scene(pattern)
    files = scene.export(file_type="gltf")
    gltf = json.loads(files["model.gltf"])
    for name, data in files.items():
        if name != "model.gltf":
            (tmp_path / name).write_bytes(data)
    (tmp_path / "paint.ktx2").write_bytes(_ktx2(pattern, "uastc"))
    gltf["images"] = [{"uri": "paint.ktx2"}]
    for texture in gltf["textures"]:
        texture["extensions"] = {"KHR_texture_basisu": {"source": texture.pop("source")}}
    (tmp_path / "quad.gltf").write_text(json.dumps(gltf))
    rgb = _render(tmp_path / "quad.gltf")
    small = pattern[2::4, 2::4].astype(float)  # 64 x 64 view of a 256 x 256 texture: every 4th texel, between two
    assert np.abs(rgb.astype(float) - small).mean() < 6.0


def test_without_the_decoder_a_one_line_error_says_what_to_install(tmp_path, monkeypatch):
    path = tmp_path / "quad.basis.glb"
    glb = _quad_scene(np.zeros((16, 16, 3), np.uint8)).export(file_type="glb")
    path.write_bytes(_with_basis_image(glb, (DATA / "quadrants.basis").read_bytes(), "image/x-basis", "GOOGLE_texture_basis"))
    monkeypatch.setitem(sys.modules, "opengl_basisu", None)  # import fails, as when it is not installed
    with pytest.raises(InputError) as error:
        load_mesh_scene(path)
    message = str(error.value)
    assert "quad.basis.glb" in message and "pip install" in message and "opengl_basisu" in message and "\n" not in message


def test_a_corrupt_basis_image_is_an_input_error(tmp_path):
    path = tmp_path / "quad.basis.glb"
    glb = _quad_scene(np.zeros((16, 16, 3), np.uint8)).export(file_type="glb")
    path.write_bytes(_with_basis_image(glb, b"\xabKTX 20\xbb\r\n\x1a\n" + b"\0" * 60, "image/ktx2", "KHR_texture_basisu"))
    with pytest.raises(InputError, match="cannot decode its Basis Universal texture") as error:
        load_mesh_scene(path)
    assert "quad.basis.glb" in str(error.value)


def test_files_without_basis_images_load_as_before(tmp_path, pattern):
    path = tmp_path / "quad.glb"
    path.write_bytes(_quad_scene(pattern).export(file_type="glb"))
    rgb = _render(path)
    assert np.abs(rgb.astype(float) - pattern[2::4, 2::4]).mean() < 6.0
