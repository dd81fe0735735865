"""Textured boxes: physical UV scale, outward winding, fitted faces."""

from __future__ import annotations

import numpy as np
from PIL import Image

from ssga_workspace_procedural.meshes import FRAME_UV, textured_box
from ssga_workspace_procedural.textures import Texture, periodic_noise

TEX = Texture("test", Image.new("RGB", (8, 8)), (0.5, 2.0))


def test_uv_is_metres_over_the_repeat_size() -> None:
    box = textured_box((0, 0, 0), (3, 1, 2), TEX, ("-y",))  # a 3 m wide, 2 m high wall facing -y
    uv = box.visual.uv
    np.testing.assert_allclose(np.ptp(uv, axis=0), [3 / 0.5, 2 / 2.0])
    # u grows to the right of a viewer facing the face (+x, for a face looking along -y), v with height
    right = box.vertices[np.argmax(uv[:, 0])]
    top = box.vertices[np.argmax(uv[:, 1])]
    assert right[0] == 3 and top[2] == 2


def test_faces_point_outwards() -> None:
    box = textured_box((0, 0, 0), (1, 2, 3), TEX)
    centre = np.array([0.5, 1.0, 1.5])
    out = box.triangles_center - centre
    assert (np.einsum("ij,ij->i", box.face_normals, out) > 0).all()
    assert box.is_watertight is False or box.volume > 0  # open where faces are left out; closed boxes are positive


def test_a_fitted_face_shows_the_whole_image_once() -> None:
    box = textured_box((0, 0, 0), (2, 0.03, 1), TEX, ("-y", "+x"), fit="-y")
    uv = box.visual.uv
    np.testing.assert_allclose(uv[:4], [[0, 0], [1, 0], [1, 1], [0, 1]])
    np.testing.assert_allclose(uv[4:], np.tile(FRAME_UV, (4, 1)))


def test_periodic_noise_tiles_seamlessly() -> None:
    n = periodic_noise(np.random.default_rng(0), (64, 64), (3.0, 3.0))
    inner = np.abs(np.diff(n, axis=1)).mean()
    seam = np.abs(n[:, 0] - n[:, -1]).mean()
    assert seam < 2 * inner
