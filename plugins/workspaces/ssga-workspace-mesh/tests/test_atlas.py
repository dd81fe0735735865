"""The texture atlas samples each packed texture as if it were alone."""

from __future__ import annotations

import numpy as np
import pytest

from ssga_workspace_mesh import atlas as atlas_module
from ssga_workspace_mesh.atlas import TextureAtlas


def bilinear_repeat(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Reference sampler: bilinear, wrapping, trimesh's uv (origin bottom-left), texel centres at half texels."""
    h, w = image.shape[:2]
    x = np.mod(uv[:, 0], 1.0) * w - 0.5
    y = np.mod(1.0 - uv[:, 1], 1.0) * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    img = image.astype(np.float64) / 255.0

    def at(yy: np.ndarray, xx: np.ndarray) -> np.ndarray:
        return img[yy % h, xx % w]

    top = at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx
    bottom = at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx
    return top * (1 - fy) + bottom * fy


@pytest.mark.parametrize("max_side", [atlas_module.MAX_SIDE, 80])
def test_atlas_matches_sampling_each_texture_alone(monkeypatch, max_side):
    monkeypatch.setattr(atlas_module, "MAX_SIDE", max_side)  # 80: forces several pages
    rng = np.random.default_rng(3)
    sizes = [(16, 32), (64, 8), (50, 50), (7, 3), (40, 70)]
    textures = [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for h, w in sizes]
    atlas = TextureAtlas.pack(textures, page_width=96)
    assert (len(atlas.pages) > 1) == (max_side == 80)
    which = rng.integers(0, len(textures), 5000)
    uv = rng.uniform(-2.0, 3.0, (5000, 2)).astype(np.float32)  # repeats, and the seams between repeats
    got = atlas.sample(which, uv)
    for k, texture in enumerate(textures):
        sel = which == k
        # cv2.remap interpolates at 1/32-texel steps: allow a few grey levels.
        np.testing.assert_allclose(got[sel], bilinear_repeat(texture, uv[sel]), atol=6 / 255)
