"""Arrays reused from call to call: per-thread scratch buffers, and cached read-only index grids."""

from __future__ import annotations

import functools
import threading

import numpy as np

_OFF_IMAGE = -8.0
"""Where "no point" reads: far enough off any image that a bilinear read there is all border (zero)."""


@functools.lru_cache(maxsize=8)
def _arange(n: int) -> np.ndarray:
    """``0 .. n - 1`` as int64 (read-only)."""
    index = np.arange(n, dtype=np.int64)
    index.flags.writeable = False
    return index


@functools.lru_cache(maxsize=8)
def _pixel_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """``(H W + 1,)`` float32 column and row of every pixel in raster order, then
    :data:`_OFF_IMAGE` (the sentinel point's); read-only."""
    row, col = (a.astype(np.float32) for a in np.divmod(np.arange(h * w + 1), w))
    col[-1] = row[-1] = _OFF_IMAGE
    col.flags.writeable = row.flags.writeable = False
    return col, row


class _Scratch(threading.local):
    """Per-thread scratch arrays, reused from call to call."""

    def __init__(self) -> None:
        self.buffers: dict[tuple[str, object, np.dtype], np.ndarray] = {}

    def get(self, name: str, shape: int | tuple[int, ...], dtype: type | np.dtype) -> np.ndarray:
        key = (name, shape, np.dtype(dtype))
        buf = self.buffers.get(key)
        if buf is None:
            if len(self.buffers) >= 160:  # many image sizes: start over rather than grow
                self.buffers.clear()
            buf = self.buffers[key] = np.empty(shape, dtype=dtype)
        return buf


_SCRATCH = _Scratch()
