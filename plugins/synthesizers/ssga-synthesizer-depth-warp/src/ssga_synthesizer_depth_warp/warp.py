"""Forward warping of an image with per-pixel depth into another pinhole camera.

The geometry, for any pinhole intrinsics ``K`` (OpenCV frame: ``x`` right, ``y`` down,
``z`` forward; planar depth; pixel centres at integers):

* each source pixel ``(u, v)`` with known depth ``z`` is the camera-frame point
  ``X = z K_src^-1 [u, v, 1]^T``;
* in the target camera it is ``X' = R X + t`` (``T_dst<-src = [R | t]``), and it lands at
  ``q = K_dst X' = z H [u, v, 1]^T + K_dst t`` with ``H = K_dst R K_src^-1``:
  ``(u', v') = (q_x / q_z, q_y / q_z)`` at depth ``z' = q_z``.

The splat is z-buffered: every source pixel draws into its nearest target pixel
(and, with ``splat > 1``, the ``splat x splat`` footprint around it) and the nearest
surface wins. The z-buffer is one ``np.minimum.at`` over a packed 64-bit key, the
target depth's float32 bits (which order like the depths, for positive floats) above
the source pixel's index, so a single sort-free pass finds both the nearest depth and
which source pixel it came from.

Footprint pixels other than a point's own nearest pixel compete with their depth
raised by ``depth_tolerance``: on one surface a pixel's own point beats its
neighbours' footprints, while a surface nearer by more than the tolerance still covers
the cracks of the one behind it (the background seen through a foreground that the
camera approached).
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from ssga_core import InputError

HoleFill = Literal["none", "inpaint", "nearest"]
HOLE_FILLS: tuple[str, ...] = ("none", "inpaint", "nearest")
"""The hole-filling methods :func:`fill_holes` knows."""

_INDEX_BITS = 32


@functools.lru_cache(maxsize=8)
def _source_index(n: int) -> np.ndarray:
    index = np.arange(n, dtype=np.int64)
    index.flags.writeable = False
    return index


@dataclass(frozen=True, eq=False)
class Warp:
    """The result of :func:`forward_warp`.

    Attributes:
        rgb: ``(H', W', ...)`` the warped image, same dtype and channels as the input;
            zero where nothing landed (unless holes were filled).
        depth: ``(H', W')`` float32 planar depth in the target camera of the surface
            drawn at each pixel; 0 where nothing landed (also where holes were filled:
            their colour is a guess, their depth unknown).
        target_uv: ``(H, W, 2)`` float32, where each *source* pixel lands in the target
            image; NaN where its depth is unknown or beyond ``max_depth``, or it is at
            or behind the target camera. Positions outside the target image are kept.
        visible: ``(H, W)`` bool, the source pixel lands inside the target image and is
            on the front-most surface there: its depth is within ``depth_tolerance``
            of the depth the z-buffer kept at its nearest target pixel.
        covered: ``(H', W')`` bool, target pixels some source pixel was drawn into
            (before hole filling).
    """

    rgb: np.ndarray
    depth: np.ndarray
    target_uv: np.ndarray
    visible: np.ndarray
    covered: np.ndarray


def _check_intrinsics(name: str, K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or tuple(K[2]) != (0.0, 0.0, 1.0) or K[1, 0] != 0.0 or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"{name}: expected pinhole intrinsics [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    return K


def reproject(
    depth: np.ndarray,
    K_src: np.ndarray,
    K_dst: np.ndarray,
    T_dst_from_src: np.ndarray,
    max_depth: float = np.inf,
) -> tuple[np.ndarray, np.ndarray]:
    """Where every source pixel lands in the target camera, and at what depth.

    Args:
        depth: ``(H, W)`` planar depths of the source pixels; ``<= 0``, non-finite or
            beyond ``max_depth`` means unknown.
        K_src: ``3 x 3`` intrinsics of the source camera.
        K_dst: ``3 x 3`` intrinsics of the target camera.
        T_dst_from_src: ``4 x 4`` (or ``3 x 4``) rigid transform taking source-camera
            points into the target camera's frame (``Pose.relative_to`` gives it).
        max_depth: source depths beyond this are treated as unknown.

    Returns:
        ``(H, W, 2)`` float32 target positions ``(u', v')`` and ``(H, W)`` float32 target
        depths ``z'``; both NaN where the depth is unknown or ``z' <= 0``.
    """
    u, v, zt = _reproject(depth, K_src, K_dst, T_dst_from_src, max_depth)
    return np.stack([u, v], axis=-1), zt


def _reproject(
    depth: np.ndarray, K_src: np.ndarray, K_dst: np.ndarray, T_dst_from_src: np.ndarray, max_depth: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`reproject` as three ``(H, W)`` arrays ``u', v', z'``; ``u'`` and ``v'`` are scratch arrays."""
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise InputError(f"reproject: expected an (H, W) depth map, got shape {depth.shape}")
    K_src = _check_intrinsics("reproject: K_src", K_src)
    K_dst = _check_intrinsics("reproject: K_dst", K_dst)
    T = np.asarray(T_dst_from_src, dtype=np.float64)
    if T.shape not in {(4, 4), (3, 4)}:
        raise InputError(f"reproject: expected a 4 x 4 transform T_dst_from_src, got shape {T.shape}")
    h, w = depth.shape
    Hm = (K_dst @ T[:3, :3] @ np.linalg.inv(K_src)).astype(np.float32)
    kt = (K_dst @ T[:3, 3]).astype(np.float32)

    # Written with in-place operations and reused scratch arrays: at these sizes fresh
    # temporaries cost more in page faults than the arithmetic does.
    z = _SCRATCH.get("depth", (h, w), np.float32)
    np.copyto(z, depth, casting="unsafe")
    with np.errstate(invalid="ignore"):
        z[~((z > 0) & (z < np.inf) & (z <= max_depth))] = np.nan
    col = np.arange(w, dtype=np.float32)[None, :]
    row = np.arange(h, dtype=np.float32)[:, None]
    qx, qy = _SCRATCH.get("u", (h, w), np.float32), _SCRATCH.get("v", (h, w), np.float32)
    zt = np.empty((h, w), dtype=np.float32)
    # q = z H [u, v, 1] + K_dst t, one row of H at a time; (1, W) + (H, 1) broadcasts to (H, W).
    for i, q in ((2, zt), (0, qx), (1, qy)):
        np.add(Hm[i, 0] * col, Hm[i, 1] * row + Hm[i, 2], out=q)
        q *= z
        q += kt[i]
    with np.errstate(invalid="ignore", divide="ignore"):
        zt[~(zt > 0)] = np.nan  # at or behind the target camera (unknown depths are NaN already)
        qx /= zt
        qy /= zt
    return qx, qy, zt


def forward_warp(
    rgb: np.ndarray,
    depth: np.ndarray,
    K_src: np.ndarray,
    K_dst: np.ndarray,
    T_dst_from_src: np.ndarray,
    out_shape: tuple[int, int] | None = None,
    *,
    splat: int = 1,
    max_depth: float = np.inf,
    fill: HoleFill = "none",
    max_hole: int = 8,
    depth_tolerance: float = 0.02,
) -> Warp:
    """Render ``rgb`` seen with ``depth`` from the source camera into the target camera.

    Args:
        rgb: ``(H, W)`` or ``(H, W, C)`` source image, any dtype (hole filling needs
            uint8 with 1 or 3 channels).
        depth: ``(H, W)`` source planar depths (unknown: ``<= 0`` or non-finite).
        K_src, K_dst: ``3 x 3`` pinhole intrinsics of the two cameras.
        T_dst_from_src: ``4 x 4`` transform from the source camera frame to the target's.
        out_shape: ``(H', W')`` of the target image; the source's if omitted.
        splat: side of the square footprint each point draws: 1 draws its nearest pixel
            only; 2 the 2 x 2 pixels around it, 3 the 3 x 3 block centred on it. Larger
            footprints close the cracks that open where the target camera is nearer to a
            surface than the source was.
        max_depth: source depths beyond this are ignored.
        fill: hole filling of the target image (see :func:`fill_holes`).
        max_hole: holes narrower than this (pixels) are filled; wider ones stay empty.
        depth_tolerance: relative depth margin of "the same surface": it decides
            ``visible`` and lets a point's own pixel beat its neighbours' footprints.

    Returns:
        the :class:`Warp`.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim not in (2, 3) or rgb.shape[:2] != np.shape(depth):
        raise InputError(f"forward_warp: image of shape {rgb.shape} does not match depth of shape {np.shape(depth)}")
    if not (isinstance(splat, int | np.integer) and 1 <= splat <= 7):
        raise InputError(f"forward_warp: splat must be an integer from 1 to 7, got {splat!r}")
    if not depth_tolerance >= 0:
        raise InputError(f"forward_warp: depth_tolerance must be >= 0, got {depth_tolerance!r}")
    h, w = rgb.shape[:2]
    oh, ow = (h, w) if out_shape is None else (int(out_shape[0]), int(out_shape[1]))
    if oh <= 0 or ow <= 0 or h * w >= 2**_INDEX_BITS:
        raise InputError(f"forward_warp: bad image sizes: source {(h, w)}, target {(oh, ow)}")

    u2, v2, zt = _reproject(depth, K_src, K_dst, T_dst_from_src, max_depth)
    uv = np.stack([u2, v2], axis=-1)

    # Every source pixel takes part; those that cannot draw (unknown depth, behind the
    # camera, off the image) write to one spare z-buffer slot past the image, which
    # costs less than compacting the arrays. Pixel indices are computed in floating
    # point so that NaN positions are replaced before any cast to int.
    n_src, spare = h * w, oh * ow
    ftype = np.float32 if spare < 2**24 else np.float64  # pixel indices must be exact
    tmp = _SCRATCH.get
    z, u, v = zt.ravel(), u2.ravel(), v2.ravel()
    with np.errstate(invalid="ignore"):
        inside = (u > -0.5) & (u < ow - 0.5) & (v > -0.5) & (v < oh - 0.5)
    own_f, col_f = tmp("own_f", n_src, ftype), tmp("col_f", n_src, ftype)
    np.rint(v, out=own_f)
    own_f *= ow
    own_f += np.rint(u, out=col_f)
    own_f[~inside] = spare
    own = tmp("own", n_src, np.intp)
    np.copyto(own, own_f, casting="unsafe")
    # Positive float32 bits order like the values; NaN depths only ever go to the spare slot.
    index = _source_index(n_src)
    own_key = tmp("own_key", n_src, np.int64)
    np.copyto(own_key, z.view(np.int32), casting="unsafe")
    own_key <<= _INDEX_BITS
    own_key |= index

    # An empty pixel's key is larger than any real one (whose depth bits are below
    # infinity's) and names source n_src: a zero appended to the sources.
    empty = (np.iinfo(np.int32).max << _INDEX_BITS) | n_src
    zbuf = tmp("zbuf", spare + 1, np.int64)
    zbuf.fill(empty)
    np.minimum.at(zbuf, own, own_key)
    if splat > 1:
        _splat_footprints(zbuf, u, v, z, index, splat, oh, ow, ftype, depth_tolerance)

    # Each target pixel's source index (n_src for none): one gather per output fills
    # every pixel, holes included.
    zbuf = zbuf[:spare]
    covered_flat = zbuf != empty
    winner = zbuf  # reused in place: the source index is in the low bits
    winner &= (1 << _INDEX_BITS) - 1
    channels = rgb.shape[2:]
    pixels = tmp("pixels", (n_src + 1, *channels), rgb.dtype)
    pixels[:n_src] = rgb.reshape(n_src, *channels)
    pixels[n_src] = 0
    # mode="clip" skips the bounds checks and the buffering of `out` (indices are valid).
    out = np.take(pixels, winner, axis=0, mode="clip")
    depths = tmp("depths", n_src + 1, np.float32)
    depths[:n_src] = z
    depths[n_src] = 0.0
    out_depth = np.empty(spare + 1, dtype=np.float32)  # the extra 0 serves `visible` below
    np.take(depths, winner, out=out_depth[:spare], mode="clip")
    out_depth[spare] = 0.0

    # Visible: on the surface the z-buffer kept at the point's own nearest pixel. The
    # spare slot's depth is 0, so points off the image are never visible.
    front = tmp("front", n_src, np.float32)
    np.take(out_depth, own, out=front, mode="clip")
    front *= np.float32(1.0 + depth_tolerance)
    with np.errstate(invalid="ignore"):
        visible = z <= front
    out_depth = out_depth[:spare]

    out = out.reshape(oh, ow, *channels)
    covered = covered_flat.reshape(oh, ow)
    if fill != "none":
        out = fill_holes(out, covered, fill, max_hole=max_hole)
    return Warp(
        rgb=out,
        depth=out_depth.reshape(oh, ow),
        target_uv=uv,
        visible=visible.reshape(h, w),
        covered=covered,
    )


def _splat_footprints(
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
    """Z-buffer every point into its whole ``splat x splat`` footprint at a raised depth.

    Each point has been drawn into its own nearest pixel at its true depth already, which
    beats its own raised key there: only the neighbours' pixels see the raised depth.
    """
    tmp = _SCRATCH.get
    n, spare = len(u), oh * ow
    far_key = tmp("far_key", n, np.int64)
    raised = tmp("raised", n, np.float32)
    np.multiply(z, np.float32(1.0 + depth_tolerance), out=raised)
    np.copyto(far_key, raised.view(np.int32), casting="unsafe")
    far_key <<= _INDEX_BITS
    far_key |= index
    # The footprint's top-left pixel is the one nearest (u - (s-1)/2, v - (s-1)/2).
    half = (splat - 1) / 2.0
    c0, r0 = tmp("c0", n, ftype), tmp("r0", n, ftype)
    np.rint(np.subtract(u, half, out=c0), out=c0)
    np.rint(np.subtract(v, half, out=r0), out=r0)
    with np.errstate(invalid="ignore"):  # NaN positions are in no row or column
        rows_in = [(r0 >= -dr) & (r0 < oh - dr) for dr in range(splat)]
        cols_in = [(c0 >= -dc) & (c0 < ow - dc) for dc in range(splat)]
    np.multiply(r0, ow, out=r0)  # r0 now holds the footprint's first row offset
    target_f, target = tmp("target_f", n, ftype), tmp("target", n, np.intp)
    for dr in range(splat):
        for dc in range(splat):
            np.add(r0, dr * ow + dc, out=target_f)
            target_f += c0
            np.copyto(target_f, spare, where=~(rows_in[dr] & cols_in[dc]))
            np.copyto(target, target_f, casting="unsafe")
            np.minimum.at(zbuf, target, far_key)


class _Scratch(threading.local):
    """Per-thread scratch arrays, reused from call to call."""

    def __init__(self) -> None:
        self.buffers: dict[tuple[str, object, np.dtype], np.ndarray] = {}

    def get(self, name: str, shape: int | tuple[int, ...], dtype: type | np.dtype) -> np.ndarray:
        key = (name, shape, np.dtype(dtype))
        buf = self.buffers.get(key)
        if buf is None:
            if len(self.buffers) >= 64:  # many image sizes: start over rather than grow
                self.buffers.clear()
            buf = self.buffers[key] = np.empty(shape, dtype=dtype)
        return buf


_SCRATCH = _Scratch()


def small_holes(covered: np.ndarray, max_hole: int) -> np.ndarray:
    """``(H, W)`` bool: the uncovered pixels in gaps narrower than ``max_hole`` pixels.

    A morphological closing of the coverage with a ``max_hole x max_hole`` square:
    cracks and pinholes close, while large empty areas (disocclusions, the part of the
    target the source never saw) do not.
    """
    if max_hole <= 1:
        return np.zeros_like(covered, dtype=bool)
    kernel = np.ones((max_hole, max_hole), np.uint8)
    closed = cv2.morphologyEx(covered.astype(np.uint8), cv2.MORPH_CLOSE, kernel)
    return (closed > 0) & ~covered


def fill_holes(image: np.ndarray, covered: np.ndarray, method: HoleFill, max_hole: int = 8) -> np.ndarray:
    """Fill the small holes of a warped image.

    Args:
        image: ``(H, W)`` or ``(H, W, C)`` image; ``"inpaint"`` needs uint8 with 1 or 3 channels.
        covered: ``(H, W)`` bool, the pixels that hold a warped value.
        method: ``"none"`` (return the image as is); ``"inpaint"`` (OpenCV's Telea
            inpainting, radius 3); ``"nearest"`` (the colour of the nearest covered pixel).
        max_hole: only holes narrower than this many pixels are filled (see
            :func:`small_holes`).

    Returns:
        a new image (the input itself for ``"none"`` or when nothing is to fill).
    """
    if method not in HOLE_FILLS:
        raise InputError(f"fill_holes: unknown method {method!r}; known: {', '.join(HOLE_FILLS)}")
    if method == "none":
        return image
    holes = small_holes(covered, max_hole)
    if not holes.any() or not covered.any():
        return image
    if method == "inpaint":
        if image.dtype != np.uint8 or (image.ndim == 3 and image.shape[2] not in (1, 3)):
            raise InputError(f"fill_holes: inpaint needs a uint8 image with 1 or 3 channels, got {image.dtype} {image.shape}")
        # Telea only looks `radius` pixels around each hole pixel; crop to the holes' box.
        v, u = np.nonzero(holes)
        pad = 4
        r0, r1 = max(v.min() - pad, 0), v.max() + pad + 1
        c0, c1 = max(u.min() - pad, 0), u.max() + pad + 1
        out = image.copy()
        out[r0:r1, c0:c1] = np.asarray(
            cv2.inpaint(np.ascontiguousarray(image[r0:r1, c0:c1]), holes[r0:r1, c0:c1].astype(np.uint8), 3, cv2.INPAINT_TELEA)
        ).reshape(out[r0:r1, c0:c1].shape)
        return out
    # Nearest: the distance transform's labels name, for every pixel, the nearest zero
    # (covered) pixel, numbered in raster order.
    _, labels = cv2.distanceTransformWithLabels(
        (~covered).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5, labelType=cv2.DIST_LABEL_PIXEL
    )
    hole_index = np.flatnonzero(holes)
    nearest = np.flatnonzero(covered)[labels.ravel()[hole_index] - 1]
    out = image.copy()
    out.reshape(covered.size, -1)[hole_index] = np.take(image.reshape(covered.size, -1), nearest, axis=0)
    return out
