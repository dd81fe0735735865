"""Texture atlas: many textures sampled in one ``cv2.remap`` call.

A view of a real scene shows a dozen textures; sampling each with its own mask and
remap call cost as much as the ray casting. Packing the textures into a few large
pages (shelf packing) makes texturing one gather of per-texture offsets and one
remap per page, whatever the number of textures.

Each texture is stored with a one-texel border copied from its opposite edge, so
bilinear filtering near an edge blends with the texel across the seam, as glTF's
default ``REPEAT`` sampler does, and never with a neighbouring texture.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

MAX_SIDE = 32000
"""Largest page side: ``cv2.remap`` needs images and maps under 32767 pixels a side."""

_ROW = 1024  # samples laid out in rows of this many, to keep the remap map under the same limit


@dataclass(frozen=True, eq=False)
class TextureAtlas:
    """Textures packed into pages.

    Attributes:
        pages: ``(H, W, 3)`` uint8 images.
        page: ``(T,)`` page of each texture.
        origin: ``(T, 2)`` float32 ``(x, y)`` of each texture's top-left texel in its page.
        size: ``(T, 2)`` float32 ``(width, height)`` of each texture.
    """

    pages: tuple[np.ndarray, ...]
    page: np.ndarray
    origin: np.ndarray
    size: np.ndarray

    @classmethod
    def pack(cls, textures: Sequence[np.ndarray], page_width: int = 4096) -> TextureAtlas:
        """Shelf-pack ``(H, W, 3)`` uint8 textures, tallest first, into pages ``page_width`` wide."""
        sizes = np.array([t.shape[:2] for t in textures], dtype=np.int64).reshape(-1, 2)  # (h, w)
        page_width = max(page_width, int(sizes[:, 1].max(initial=0)) + 2)
        placement = np.zeros((len(textures), 3), dtype=np.int64)  # page, x, y of the bordered block
        heights: list[int] = [0]
        x = y = shelf = 0
        for i in np.argsort(-sizes[:, 0], kind="stable"):
            h, w = sizes[i] + 2
            if x + w > page_width:
                x, y, shelf = 0, y + shelf, 0
            if y + h > MAX_SIDE:
                heights.append(0)
                x = y = shelf = 0
            placement[i] = (len(heights) - 1, x, y)
            x, shelf = x + w, max(shelf, h)
            heights[-1] = max(heights[-1], y + h)
        pages = [np.zeros((max(ph, 1), page_width, 3), dtype=np.uint8) for ph in heights]
        for texture, (p, px, py) in zip(textures, placement, strict=True):
            h, w = texture.shape[:2]
            pages[p][py : py + h + 2, px : px + w + 2] = cv2.copyMakeBorder(texture, 1, 1, 1, 1, cv2.BORDER_WRAP)
        return cls(
            pages=tuple(pages),
            page=placement[:, 0].astype(np.int32),
            origin=(placement[:, 1:] + 1).astype(np.float32),
            size=sizes[:, ::-1].astype(np.float32),
        )

    def sample(self, texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Bilinear, repeating samples ``(N, 3)`` in ``[0, 1]`` of textures ``(N,)`` at ``(N, 2)`` uvs.

        ``uv`` follows trimesh, which flips glTF's ``v`` on load: ``(0, 0)`` is the
        image's bottom-left corner, ``(1, 1)`` its top-right. Texel centres sit at
        half-integer multiples of the texel size, as in OpenGL.
        """
        origin = np.take(self.origin, texture, axis=0)
        size = np.take(self.size, texture, axis=0)
        x = origin[:, 0] - 0.5 + np.mod(uv[:, 0], 1.0) * size[:, 0]
        y = origin[:, 1] - 0.5 + np.mod(1.0 - uv[:, 1], 1.0) * size[:, 1]
        if len(self.pages) == 1:
            return _remap(self.pages[0], x, y)
        out = np.empty((len(texture), 3), dtype=np.float32)
        page = np.take(self.page, texture)
        for p in np.unique(page):
            sel = np.flatnonzero(page == p)
            out[sel] = _remap(self.pages[p], x[sel], y[sel])
        return out


def _remap(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    n = len(x)
    rows = max(1, -(-n // _ROW))
    maps = np.zeros((2, rows * _ROW), dtype=np.float32)
    maps[0, :n], maps[1, :n] = x, y
    shape = (rows, _ROW)
    out = cv2.remap(image, maps[0].reshape(shape), maps[1].reshape(shape), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:n].astype(np.float32) * np.float32(1.0 / 255.0)
