"""The point cloud: every pixel of the source views moved into the target camera, numbered in one atlas."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ssga_synthesizer_depth_warp.frames import _Frames, _local_frames, _offsets
from ssga_synthesizer_depth_warp.projection import _reproject
from ssga_synthesizer_depth_warp.scratch import _SCRATCH
from ssga_synthesizer_depth_warp.surface import surface_links


@dataclass(frozen=True, eq=False)
class Source:
    """One view for :func:`forward_warp_many`: its image, depth, intrinsics and where it is.

    Attributes:
        rgb: ``(H, W)`` or ``(H, W, C)`` image; all sources of one warp share dtype and channels.
        depth: ``(H, W)`` planar depths (unknown: ``<= 0`` or non-finite).
        K: ``3 x 3`` pinhole intrinsics.
        T_dst_from_src: ``4 x 4`` transform from this camera's frame to the target's.
        links: :func:`surface_links` of ``depth`` (with the warp's ``depth_edge`` and
            ``max_depth``) if computed already: they depend on the view alone, so a view
            warped to many targets computes them once.
    """

    rgb: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    T_dst_from_src: np.ndarray
    links: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class _Cloud:
    """Every source pixel moved into the target camera.

    The points are numbered like the pixels of an *atlas*: the sources stacked top to
    bottom, padded to the widest (padding points have unknown depth). So a point's right
    neighbour is the next index and its lower one ``width`` further, whichever source it
    belongs to, and one remap of the atlas reads any source. The per-point arrays hold
    ``size + 1`` entries, the last a sentinel for "no point" that the z-buffer's empty
    pixels name, so that gathers need no masking. They are per-thread scratch arrays,
    valid until the next warp.

    Attributes:
        u, v, z: target column, row and depth of each point (NaN: unknown; the sentinel's 0).
        frames: the points' frames, or None where not needed.
        width: the atlas's width.
        rows: where each source's rows begin in the atlas, then the atlas's height.
        target_uv: per source, its ``(H, W, 2)`` point map.
    """

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    frames: _Frames | None
    width: int
    rows: list[int]
    target_uv: list[np.ndarray]

    @property
    def size(self) -> int:
        return self.rows[-1] * self.width

    def source_part(self, values: np.ndarray, k: int) -> np.ndarray:
        """Source ``k``'s ``(H, W)`` part of per-point ``values``."""
        h, w = self.target_uv[k].shape[:2]
        return values[: self.size].reshape(-1, self.width)[self.rows[k] : self.rows[k] + h, :w]

    def atlas(self, images: list[np.ndarray]) -> np.ndarray:
        """The sources' images stacked like the points (the image itself for one source)."""
        if len(images) == 1:
            return np.ascontiguousarray(images[0])
        out = np.zeros((self.rows[-1], self.width, *images[0].shape[2:]), dtype=images[0].dtype)
        for image, row in zip(images, self.rows, strict=False):
            out[row : row + image.shape[0], : image.shape[1]] = image
        return out


def _move(sources: list[Source], K_dst: np.ndarray, max_depth: float, depth_edge: float | None) -> _Cloud:
    """Reproject every source into the target camera; with ``depth_edge``, also find the points' frames."""
    tmp = _SCRATCH.get
    width = max(np.shape(s.depth)[1] for s in sources)
    rows = np.concatenate([[0], np.cumsum([np.shape(s.depth)[0] for s in sources])]).tolist()
    n = rows[-1] * width
    u, v, z = tmp("cloud_u", n + 1, np.float32), tmp("cloud_v", n + 1, np.float32), tmp("cloud_z", n + 1, np.float32)
    links = tmp("cloud_links", n + 1, np.uint8) if depth_edge is not None else None
    if any(np.shape(s.depth)[1] != width for s in sources):  # padding points: unknown, unlinked
        for values in (u, v, z):
            values.fill(np.nan)
        if links is not None:
            links.fill(0)
    u[n] = v[n] = z[n] = 0.0
    target_uv = []
    for source, row in zip(sources, rows, strict=False):
        h, w = np.shape(source.depth)
        part = (slice(row, row + h), slice(0, w))
        qx, qy, zt, _ = _reproject(source.depth, source.K, K_dst, source.T_dst_from_src, max_depth)
        for values, mine in ((u, qx), (v, qy), (z, zt)):
            values[:n].reshape(-1, width)[part] = mine
        target_uv.append(np.stack([qx, qy], axis=-1))
        if links is not None and depth_edge is not None:
            given = source.links if source.links is not None else surface_links(source.depth, depth_edge, max_depth)
            links[:n].reshape(-1, width)[part] = given
    frames = _local_frames(u, v, links, width) if links is not None else None
    return _Cloud(u, v, z, frames, width, rows, target_uv)


def _map_back(cloud: _Cloud, point: np.ndarray, col: np.ndarray, row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where target pixels ``(col, row)`` map back to in the source, as offsets from ``point``'s pixel.

    Meaningless (even NaN) for points without a frame: callers check :attr:`_Frames.framed`.
    """
    assert cloud.frames is not None
    inverse = [np.take(entry, point, mode="clip") for entry in cloud.frames.inverse]
    dx = np.take(cloud.u, point, mode="clip")
    np.subtract(col, dx, out=dx)
    dy = np.take(cloud.v, point, mode="clip")
    np.subtract(row, dy, out=dy)
    back_x, back_y = np.empty_like(dx), np.empty_like(dy)
    with np.errstate(invalid="ignore"):
        _offsets(inverse, dx, dy, back_x, back_y, np.empty_like(dx))
    return back_x, back_y
