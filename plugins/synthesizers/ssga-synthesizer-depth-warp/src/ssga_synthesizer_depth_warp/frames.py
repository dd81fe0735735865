"""The points' local frames: the parallelogram each source pixel becomes in the target.

Where a point's right and lower neighbours are on its surface (:mod:`.surface`), the
steps to their target positions are the columns of the warp's local Jacobian ``J``: the
parallelogram the point's pixel becomes in the target, its *frame* (not where
degenerate or mirrored: the target sees that surface edge-on or from behind).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ssga_synthesizer_depth_warp.scratch import _SCRATCH, _pixel_grid
from ssga_synthesizer_depth_warp.surface import _LINKED, INTERIOR

_REACH = 0.6
"""A target pixel is in a point's footprint if it maps back within this many source
pixels of it (Chebyshev): half a pixel, and a margin so that neighbouring footprints,
each linearised about its own point, leave no crack between them."""
_MIN_AREA = 1e-6
"""Smallest area (target pixels) of a frame that is not degenerate."""


@dataclass(frozen=True, eq=False)
class _Frames:
    """The points' frames (the module docstring), and where their own pixels read.

    Attributes:
        inverse: the inverse Jacobian's entries ``(i00, i01, i10, i11)``, each ``(N,)``
            float32: a target offset ``(dx, dy)`` from the point maps back to the source
            offset ``(i00 dx + i01 dy, i10 dx + i11 dy)``; meaningless where it has no
            frame.
        framed: ``(N + 1,)`` bool, the point has a frame.
        interior: ``(N + 1,)`` bool, it has one and all four neighbours are on its
            surface, so a bilinear read within a pixel of it stays there.
        reach: ``(N + 1,)`` float32, how far (source pixels, Chebyshev) a target pixel
            may map back from the point and be in its footprint: a whole pixel from an
            interior point (that reads the same position as the neighbour whose
            footprint it is, and crosses no edge), :data:`_REACH` from another with a
            frame, and -1 (never) without one.
        read_x, read_y: ``(N + 1,)`` float32, where in the atlas the point's own pixel
            reads (see :func:`_to_reads`); the sentinel's is far off the atlas.
    """

    inverse: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    framed: np.ndarray
    interior: np.ndarray
    reach: np.ndarray
    read_x: np.ndarray
    read_y: np.ndarray


def _local_frames(u: np.ndarray, v: np.ndarray, links: np.ndarray, width: int) -> _Frames:
    """The frames of points at target ``(u, v)`` with :func:`surface_links` bits ``links`` (atlas order)."""
    tmp = _SCRATCH.get
    n = len(u) - 1
    # Forward differences over the flat arrays: the next element is the right neighbour,
    # ``width`` further the lower one (where there is none, the links say so).
    ax, ay, bx, by = (tmp(name, n, np.float32) for name in ("ax", "ay", "bx", "by"))
    np.subtract(u[1:], u[:-1], out=ax)
    np.subtract(v[1:], v[:-1], out=ay)
    np.subtract(u[width:n], u[: n - width], out=bx[: n - width])
    np.subtract(v[width:n], v[: n - width], out=by[: n - width])
    bx[n - width :] = by[n - width :] = 0.0
    det, product = tmp("det", n, np.float32), tmp("product", n, np.float32)
    np.multiply(ax, by, out=det)
    det -= np.multiply(bx, ay, out=product)
    framed, interior = tmp("framed", n + 1, bool), tmp("interior", n + 1, bool)
    bits = tmp("bits", n, np.uint8)
    np.bitwise_and(links[:n], np.uint8(_LINKED), out=bits)
    np.equal(bits, np.uint8(_LINKED), out=framed[:n])
    np.bitwise_and(links[:n], np.uint8(INTERIOR), out=bits)
    np.not_equal(bits, 0, out=interior[:n])
    with np.errstate(invalid="ignore", divide="ignore"):
        framed[:n] &= det > _MIN_AREA  # also false for NaN (a neighbour behind the camera)
        np.divide(np.float32(1.0), det, out=det)  # det holds 1 / det from here
        # J^-1 = [[by, -bx], [-ay, ax]] / det, computed in place over the steps.
        by *= det
        ax *= det
        np.negative(det, out=det)
        bx *= det
        ay *= det
    framed[n] = False
    interior &= framed
    reach, scratch = tmp("reach", n + 1, np.float32), tmp("reach_scratch", n + 1, np.float32)
    np.multiply(framed, np.float32(_REACH + 1.0), out=reach)
    reach += np.multiply(interior, np.float32(1.0 - _REACH), out=scratch)
    reach -= np.float32(1.0)
    # The own pixel's centre is (rint(u), rint(v)): map its offset from the point back.
    dx, dy = tmp("own_dx", n, np.float32), tmp("own_dy", n, np.float32)
    np.subtract(np.rint(u[:n], out=dx), u[:n], out=dx)
    np.subtract(np.rint(v[:n], out=dy), v[:n], out=dy)
    read_x, read_y = tmp("read_x", n + 1, np.float32), tmp("read_y", n + 1, np.float32)
    with np.errstate(invalid="ignore"):
        _offsets((by, bx, ay, ax), dx, dy, read_x[:n], read_y[:n], product)
    read_x[n] = read_y[n] = 0.0
    _to_reads(read_x, read_y, interior, *_pixel_grid(n // width, width))
    inverse = (by, bx, ay, ax)  # gathers clip at the last point: the sentinel, unframed, has none
    return _Frames(inverse, framed, interior, reach, read_x, read_y)


def _offsets(
    inverse: Sequence[np.ndarray], dx: np.ndarray, dy: np.ndarray, out_x: np.ndarray, out_y: np.ndarray, scratch: np.ndarray
) -> None:
    """Source offsets ``J^-1 (dx, dy)`` per point, from the inverse's four entries ``[i00, i01, i10, i11]``."""
    i00, i01, i10, i11 = inverse
    np.multiply(i00, dx, out=out_x)
    out_x += np.multiply(i01, dy, out=scratch)
    np.multiply(i10, dx, out=out_y)
    out_y += np.multiply(i11, dy, out=scratch)


def _to_reads(x: np.ndarray, y: np.ndarray, interior: np.ndarray, col: np.ndarray, row: np.ndarray) -> None:
    """Turn source offsets from points into where in the atlas to read, in place.

    An interior point reads within a pixel of its own; any other reads its own pixel, so
    that no bilinear read mixes two surfaces. ``col`` and ``row`` are the points' pixels
    in the atlas.
    """
    for offset, base in ((x, col), (y, row)):
        # fmax and fmin clip NaN (no frame) to a number too, which the mask then zeroes.
        np.fmax(offset, -1.0, out=offset)
        np.fmin(offset, 1.0, out=offset)
        offset *= interior
        offset += base
