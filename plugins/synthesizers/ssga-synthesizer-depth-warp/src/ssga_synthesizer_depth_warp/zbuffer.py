"""The z-buffer: which point each target pixel shows.

Z-buffer. Every source pixel (a *point*) draws into its nearest target pixel, its *own*
pixel, and the nearest surface wins. The z-buffer is one ``np.minimum.at`` over a packed
64-bit key, the target depth's float32 bits (which order like the depths, for positive
floats) above the point's index, so a single sort-free pass finds both the nearest
depth and which point it came from. Several source views render jointly by numbering
all their pixels in one index space: one z-buffer, one hole filling.

Squares. With ``splat > 1`` every point also draws a fixed square, at its depth raised
by ``depth_tolerance`` so that on one surface a pixel's own point wins.
"""

from __future__ import annotations

import numpy as np

from ssga_synthesizer_depth_warp.cloud import _Cloud
from ssga_synthesizer_depth_warp.scratch import _SCRATCH, _arange

_INDEX_BITS = 32


def _zbuffer(cloud: _Cloud, oh: int, ow: int, splat: int, depth_tolerance: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The z-buffer's keys ``(H' W' + 1,)`` (a spare slot last), each point's own pixel ``(N,)``, and the empty key."""
    # Every point takes part; those that cannot draw (unknown depth, behind the camera,
    # off the image) write to one spare z-buffer slot past the image, which costs less
    # than compacting the arrays. Pixel indices are computed in floating point so that
    # NaN positions are replaced before any cast to int.
    n, spare = cloud.size, oh * ow
    u, v, z = cloud.u[:n], cloud.v[:n], cloud.z[:n]
    ftype = np.float32 if spare < 2**24 else np.float64  # pixel indices must be exact
    tmp = _SCRATCH.get
    with np.errstate(invalid="ignore"):
        inside = (u > -0.5) & (u < ow - 0.5) & (v > -0.5) & (v < oh - 0.5)
    own_f, col_f = tmp("own_f", n, ftype), tmp("col_f", n, ftype)
    np.rint(v, out=own_f)
    own_f *= ow
    own_f += np.rint(u, out=col_f)
    own_f[~inside] = spare
    own = tmp("own", n, np.intp)
    np.copyto(own, own_f, casting="unsafe")
    index = _arange(n)
    # Positive float32 bits order like the values; NaN depths only ever go to the spare slot.
    own_key = tmp("own_key", n, np.int64)
    np.copyto(own_key, z.view(np.int32), casting="unsafe")
    own_key <<= _INDEX_BITS
    own_key |= index

    # An empty pixel's key is larger than any real one (whose depth bits are below
    # infinity's) and names the sentinel point n.
    empty = (np.iinfo(np.int32).max << _INDEX_BITS) | n
    zbuf = tmp("zbuf", spare + 1, np.int64)
    zbuf.fill(empty)
    np.minimum.at(zbuf, own, own_key)
    if splat > 1:
        _splat_squares(zbuf, u, v, z, index, splat, oh, ow, ftype, depth_tolerance)
    return zbuf, own, empty


def _splat_squares(
    zbuf: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    z: np.ndarray,
    index: np.ndarray,
    splat: int,
    oh: int,
    ow: int,
    ftype: type,
    depth_tolerance: float,
) -> None:
    """Z-buffer every point into its whole ``splat x splat`` square at a raised depth.

    Each point has been drawn into its own pixel at its true depth already, which beats
    its own raised key there: only the neighbours' pixels see the raised depth.
    """
    tmp = _SCRATCH.get
    n, spare = len(u), oh * ow
    far_key = tmp("far_key", n, np.int64)
    raised = tmp("raised", n, np.float32)
    np.multiply(z, np.float32(1.0 + depth_tolerance), out=raised)
    np.copyto(far_key, raised.view(np.int32), casting="unsafe")
    far_key <<= _INDEX_BITS
    far_key |= index
    # The square's top-left pixel is the one nearest (u - (s-1)/2, v - (s-1)/2).
    half = (splat - 1) / 2.0
    c0, r0 = tmp("c0", n, ftype), tmp("r0", n, ftype)
    np.rint(np.subtract(u, half, out=c0), out=c0)
    np.rint(np.subtract(v, half, out=r0), out=r0)
    with np.errstate(invalid="ignore"):  # NaN positions are in no row or column
        rows_in = [(r0 >= -dr) & (r0 < oh - dr) for dr in range(splat)]
        cols_in = [(c0 >= -dc) & (c0 < ow - dc) for dc in range(splat)]
    np.multiply(r0, ow, out=r0)  # r0 now holds the square's first row offset
    target_f, target = tmp("target_f", n, ftype), tmp("target", n, np.intp)
    for dr in range(splat):
        for dc in range(splat):
            np.add(r0, dr * ow + dc, out=target_f)
            target_f += c0
            np.copyto(target_f, spare, where=~(rows_in[dr] & cols_in[dc]))
            np.copyto(target, target_f, casting="unsafe")
            np.minimum.at(zbuf, target, far_key)
