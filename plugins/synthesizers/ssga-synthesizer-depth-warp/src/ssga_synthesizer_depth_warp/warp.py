"""Forward warping of images with per-pixel depth into another pinhole camera.

The geometry, for any pinhole intrinsics ``K`` (OpenCV frame: ``x`` right, ``y`` down,
``z`` forward; planar depth; pixel centres at integers):

* each source pixel ``(u, v)`` with known depth ``z`` is the camera-frame point
  ``X = z K_src^-1 [u, v, 1]^T``;
* in the target camera it is ``X' = R X + t`` (``T_dst<-src = [R | t]``), and it lands at
  ``q = K_dst X' = z H [u, v, 1]^T + K_dst t`` with ``H = K_dst R K_src^-1``:
  ``(u', v') = (q_x / q_z, q_y / q_z)`` at depth ``z' = q_z``.

Z-buffer. Every source pixel (a *point*) draws into its nearest target pixel, its *own*
pixel, and the nearest surface wins. The z-buffer is one ``np.minimum.at`` over a packed
64-bit key, the target depth's float32 bits (which order like the depths, for positive
floats) above the point's index, so a single sort-free pass finds both the nearest
depth and which point it came from. Several source views render jointly by numbering
all their pixels in one index space: one z-buffer, one hole filling.

Surfaces. Two neighbouring source pixels lie on one surface unless their inverse depths
differ by more than ``depth_edge`` (relative) *and* by that much more than a
neighbouring step does: a floor seen at a grazing angle changes depth fast from row to
row, but evenly (:func:`surface_links`). Where a point's right and lower neighbours are
on its surface, the steps to their target positions are the columns of the warp's
local Jacobian ``J``: the parallelogram the point's pixel becomes in the target, its
*frame* (not where degenerate or mirrored: the target sees that surface edge-on or from
behind).

Footprints (``footprint="adaptive"``). A point also covers the target pixels whose
centres map back, through ``J^-1``, into its source pixel (plus a margin), so a surface
the target sees magnified stays closed however close it comes, and hides what is behind
it. Rather than scatter every point into its footprint, the empty target pixels and the
drawn ones farther than a neighbour (a crack in a nearer surface, showing what is
behind) ask the nearest point drawn on its own pixel, which one distance transform
finds for all; where the pixel is not in that point's footprint, steps across the
source grid towards where it maps back find the one it is in. A footprint pixel is taken
only if nearer than what is drawn there by ``depth_tolerance``. Nothing spans a depth
edge: a point without a frame covers its own pixel only, so foreground and background
never smear into "rubber sheets". With ``splat > 1`` every point also draws a fixed
square, at its depth raised by ``depth_tolerance`` so that on one surface a pixel's own
point wins.

Resampling (``resample="bilinear"``). A drawn pixel reads its colour bilinearly where its
centre maps back to in the source, through its point's ``J^-1``: exact to first order,
where the point's own colour is up to 0.7 px off. Only points whose four neighbours are
on their surface read between pixels (within one of their own), so no read mixes two
surfaces. Small holes filled ``"nearest"`` read the same way, through the point drawn at
the nearest drawn pixel: a crack in a surface gets that surface's colour at the crack.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple

import cv2
import numpy as np

from ssga_core import InputError

HoleFill = Literal["none", "inpaint", "nearest"]
HOLE_FILLS: tuple[str, ...] = ("none", "inpaint", "nearest")
"""The hole-filling methods :func:`fill_holes` knows."""
Footprint = Literal["adaptive", "square"]
Resample = Literal["bilinear", "nearest"]

LINKED_RIGHT, LINKED_DOWN, INTERIOR = 1, 2, 4
"""The bits of :func:`surface_links`: the pixel is on one surface with its right
neighbour, with its lower neighbour, and with all four."""
_LINKED = LINKED_RIGHT | LINKED_DOWN

_INDEX_BITS = 32
_REACH = 0.6
"""A target pixel is in a point's footprint if it maps back within this many source
pixels of it (Chebyshev): half a pixel, and a margin so that neighbouring footprints,
each linearised about its own point, leave no crack between them."""
_STEPS = 2
"""Steps across the source grid (one pixel each) a footprint query may take."""
_MIN_AREA = 1e-6
"""Smallest area (target pixels) of a frame that is not degenerate."""
_FAR = 1e30
"""A depth farther than any surface (and still finite when raised by the tolerance)."""
_OFF_IMAGE = -8.0
"""Where "no point" reads: far enough off any image that a bilinear read there is all border (zero)."""
_REMAP_LIMIT = 32767
"""OpenCV's remap reads positions as 16-bit integers: stacked sources must stay below this many rows and columns."""


@dataclass(frozen=True, eq=False)
class Warp:
    """The result of :func:`forward_warp` (or one source's of :func:`forward_warp_many`).

    Attributes:
        rgb: ``(H', W', ...)`` the warped image, same dtype and channels as the input;
            zero where nothing landed (unless holes were filled).
        depth: ``(H', W')`` float32 planar depth in the target camera of the surface
            drawn at each pixel (its point's); 0 where nothing landed (also where holes
            were filled: their colour is a guess, their depth unknown).
        target_uv: ``(H, W, 2)`` float32, where each *source* pixel lands in the target
            image; NaN where its depth is unknown or beyond ``max_depth``, or it is at
            or behind the target camera. Positions outside the target image are kept.
        visible: ``(H, W)`` bool, the source pixel lands inside the target image and is
            on the front-most surface there: its depth is within ``depth_tolerance``
            of the depth the z-buffer kept at its nearest target pixel.
        covered: ``(H', W')`` bool, target pixels some point was drawn into (before
            hole filling).
    """

    rgb: np.ndarray
    depth: np.ndarray
    target_uv: np.ndarray
    visible: np.ndarray
    covered: np.ndarray


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
    u, v, zt, _ = _reproject(depth, K_src, K_dst, T_dst_from_src, max_depth)
    return np.stack([u, v], axis=-1), zt


def _reproject(
    depth: np.ndarray, K_src: np.ndarray, K_dst: np.ndarray, T_dst_from_src: np.ndarray, max_depth: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`reproject` as three ``(H, W)`` arrays ``u', v', z'``, and the source depth (NaN: unknown).

    ``u'``, ``v'`` and the source depth are scratch arrays, overwritten by the next call.
    """
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
    return qx, qy, zt, z


def surface_links(depth: np.ndarray, depth_edge: float = 0.03, max_depth: float = np.inf) -> np.ndarray:
    """Which neighbours of each pixel lie on its surface (the module docstring says how that is decided).

    Args:
        depth: ``(H, W)`` planar depths (unknown: ``<= 0``, non-finite, or beyond
            ``max_depth``: linked to nothing).
        depth_edge: relative inverse-depth step, beyond the neighbouring steps, that
            separates two surfaces.
        max_depth: depths beyond this are unknown.

    Returns:
        ``(H, W)`` uint8 of the bits :data:`LINKED_RIGHT`, :data:`LINKED_DOWN` and
        :data:`INTERIOR`.
    """
    depth = np.asarray(depth, dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.float32(1.0) / depth
        inverse[~((depth > 0) & (depth <= max_depth))] = np.nan  # NaN compares false: no link
    right, down = _links_along(inverse, depth_edge, 1), _links_along(inverse, depth_edge, 0)
    interior = right & down
    interior[:, 1:] &= right[:, :-1]
    interior[1:] &= down[:-1]
    interior[:, 0] = interior[0] = False
    links = right.view(np.uint8) * np.uint8(LINKED_RIGHT)
    links |= down.view(np.uint8) * np.uint8(LINKED_DOWN)
    links |= interior.view(np.uint8) * np.uint8(INTERIOR)
    return links


def _links_along(inverse: np.ndarray, depth_edge: float, axis: int) -> np.ndarray:
    """``(H, W)`` bool: whether a pixel is on one surface with its next neighbour along ``axis``."""
    head = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
    tail = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
    step = np.diff(inverse, axis=axis)
    allowed = np.maximum(inverse[tail], inverse[head])  # relative to the nearer of the two
    allowed *= np.float32(depth_edge)
    # Inverse depth is affine in the image on a plane: a step as large as the one
    # beside it is a ramp (a floor at a grazing angle), not an edge.
    bend = np.abs(np.diff(step, axis=axis))
    links = np.zeros(inverse.shape, dtype=bool)
    linked = links[head]
    with np.errstate(invalid="ignore"):
        np.less_equal(np.abs(step), allowed, out=linked)
        linked[tail] |= bend <= allowed[tail]
        linked[head] |= bend <= allowed[head]
    return links


def forward_warp(
    rgb: np.ndarray,
    depth: np.ndarray,
    K_src: np.ndarray,
    K_dst: np.ndarray,
    T_dst_from_src: np.ndarray,
    out_shape: tuple[int, int] | None = None,
    *,
    splat: int = 1,
    footprint: Footprint = "square",
    max_footprint: int = 32,
    resample: Resample = "bilinear",
    depth_edge: float = 0.03,
    max_depth: float = np.inf,
    fill: HoleFill = "none",
    max_hole: int = 16,
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
        splat, footprint, max_footprint, resample, depth_edge, max_depth, fill,
            max_hole, depth_tolerance: as for :func:`forward_warp_many`.

    Returns:
        the :class:`Warp`.
    """
    out_shape = np.shape(depth)[:2] if out_shape is None else out_shape
    return forward_warp_many(
        [Source(rgb, depth, K_src, T_dst_from_src)], K_dst, out_shape,  # type: ignore[arg-type]
        splat=splat, footprint=footprint, max_footprint=max_footprint, resample=resample, depth_edge=depth_edge,
        max_depth=max_depth, fill=fill, max_hole=max_hole, depth_tolerance=depth_tolerance,
    )[0]  # fmt: skip


def forward_warp_many(
    sources: Sequence[Source],
    K_dst: np.ndarray,
    out_shape: tuple[int, int],
    *,
    splat: int = 1,
    footprint: Footprint = "square",
    max_footprint: int = 32,
    resample: Resample = "bilinear",
    depth_edge: float = 0.03,
    max_depth: float = np.inf,
    fill: HoleFill = "none",
    max_hole: int = 16,
    depth_tolerance: float = 0.02,
) -> list[Warp]:
    """Render several source views, fused into one point cloud, into one target camera.

    All the sources' points go through one z-buffer, so every pixel shows the nearest
    surface any source saw, and holes are filled once, after fusion. With one source
    this is :func:`forward_warp`.

    Args:
        sources: the views; their images share dtype and channels, sizes may differ.
        K_dst: ``3 x 3`` pinhole intrinsics of the target camera.
        out_shape: ``(H', W')`` of the target image.
        splat: side of a square every point draws as well: 1 nothing beyond its own
            pixel, 2 the 2 x 2 pixels around it, 3 the 3 x 3 block centred on it (1 to 7).
        footprint: ``"adaptive"``: points also cover the target pixels their source
            pixels spread over (the module docstring), so surfaces seen magnified stay
            closed; ``"square"``: only the ``splat`` square.
        max_footprint: adaptive footprints reach at most half this many pixels from a
            drawn pixel; surfaces magnified more open cracks.
        resample: ``"bilinear"``: read each drawn pixel's colour at the sub-pixel
            position it maps back to in the source; ``"nearest"``: copy its point's.
            Images OpenCV cannot remap (dtypes other than uint8, uint16, int16, float32
            and float64, over 4 channels, or sources of 32767 rows or more in all) are
            resampled ``"nearest"``.
        depth_edge: relative inverse-depth step between neighbouring source pixels,
            beyond the neighbouring steps, that separates two surfaces (> 0; see
            :func:`surface_links`).
        max_depth: source depths beyond this are ignored.
        fill: hole filling of the target image (see :func:`fill_holes`); resampled
            bilinearly, ``"nearest"`` reads a hole where it maps back through the point
            drawn at the nearest drawn pixel, rather than copy that pixel's colour.
        max_hole: holes narrower than this (pixels) are filled; wider ones stay empty.
        depth_tolerance: relative depth margin of "the same surface": it decides
            ``visible``, and what a footprint or square may cover.

    Returns:
        one :class:`Warp` per source, in order. They share ``rgb``, ``depth`` and
        ``covered`` (the fused render); each has its own ``target_uv``, and a
        ``visible`` that holds where its point is on the front-most surface of the
        fused cloud.
    """
    sources = list(sources)
    label = "forward_warp" if len(sources) == 1 else "forward_warp_many"
    _check_options(label, sources, out_shape, splat, footprint, resample, max_footprint, depth_edge, depth_tolerance)
    oh, ow = int(out_shape[0]), int(out_shape[1])
    images = [np.asarray(s.rgb) for s in sources]
    adaptive = footprint == "adaptive"
    bilinear = resample == "bilinear" and _remappable(images)
    cloud = _move(sources, K_dst, max_depth, depth_edge if adaptive or bilinear else None)

    zbuf, own, empty = _zbuffer(cloud, oh, ow, splat, depth_tolerance)
    # Each target pixel's winning point (the sentinel n for none) and its depth.
    n, spare = cloud.size, oh * ow
    keys = zbuf[:spare]
    covered = (keys != empty).reshape(oh, ow)
    winner = keys  # reused in place: the point's index is in the low bits
    winner &= (1 << _INDEX_BITS) - 1
    front = np.empty(spare + 1, dtype=np.float32)  # the extra 0 serves `visible` below
    np.take(cloud.z, winner, out=front[:spare], mode="clip")
    front[spare] = 0.0
    nearest, footprints = _spread(cloud, winner, covered, front, max_footprint, depth_tolerance) if adaptive else (None, None)
    if bilinear:
        # Small holes read the surface of the nearest drawn point, where they map back to
        # through its frame (within a pixel of it), rather than copy that pixel's colour.
        holes = _hole_reads(cloud, winner, covered, max_hole, nearest) if fill == "nearest" else None
        out = _resample_bilinear(cloud, images, winner, covered.shape, [footprints, holes], own if splat > 1 else None)
        fill = "none" if holes is not None else fill
    else:
        out = _resample_nearest(cloud, images, winner, covered.shape)
    out_depth = front[:spare].reshape(oh, ow)

    # Visible: on the surface the z-buffer kept at the point's own pixel. The spare
    # slot's depth is 0, so points off the image are never visible.
    point_front = _SCRATCH.get("point_front", n, np.float32)
    np.take(front, own, out=point_front, mode="clip")
    point_front *= np.float32(1.0 + depth_tolerance)
    with np.errstate(invalid="ignore"):
        visible = cloud.z[:n] <= point_front
    if fill != "none":
        out = _fill(out, covered, fill, max_hole, nearest)
    return [
        Warp(rgb=out, depth=out_depth, target_uv=uv, visible=cloud.source_part(visible, k), covered=covered)
        for k, uv in enumerate(cloud.target_uv)
    ]


def _check_options(
    label: str,
    sources: list[Source],
    out_shape: tuple[int, int],
    splat: int,
    footprint: str,
    resample: str,
    max_footprint: int,
    depth_edge: float,
    depth_tolerance: float,
) -> None:
    if not sources:
        raise InputError(f"{label}: no source to warp")
    first = np.asarray(sources[0].rgb)
    for k, source in enumerate(sources):
        where = label if len(sources) == 1 else f"{label}: source {k}"
        rgb = np.asarray(source.rgb)
        if rgb.ndim not in (2, 3) or rgb.shape[:2] != np.shape(source.depth):
            raise InputError(f"{where}: image of shape {rgb.shape} does not match depth of shape {np.shape(source.depth)}")
        if rgb.dtype != first.dtype or rgb.shape[2:] != first.shape[2:]:
            raise InputError(f"{where}: image of {rgb.dtype} {rgb.shape} differs in dtype or channels from the first one's")
        if source.links is not None and (np.shape(source.links) != rgb.shape[:2] or np.asarray(source.links).dtype != np.uint8):
            raise InputError(f"{where}: links must be the surface_links() of its depth, a {rgb.shape[:2]} uint8 array")
    if not (isinstance(splat, int | np.integer) and 1 <= splat <= 7):
        raise InputError(f"{label}: splat must be an integer from 1 to 7, got {splat!r}")
    if footprint not in ("adaptive", "square"):
        raise InputError(f"{label}: footprint must be 'adaptive' or 'square', got {footprint!r}")
    if resample not in ("bilinear", "nearest"):
        raise InputError(f"{label}: resample must be 'bilinear' or 'nearest', got {resample!r}")
    if not (isinstance(max_footprint, int | np.integer) and max_footprint >= 1):
        raise InputError(f"{label}: max_footprint must be an integer >= 1, got {max_footprint!r}")
    if not depth_edge > 0:
        raise InputError(f"{label}: depth_edge must be > 0, got {depth_edge!r}")
    if not depth_tolerance >= 0:
        raise InputError(f"{label}: depth_tolerance must be >= 0, got {depth_tolerance!r}")
    rows, width = sum(np.shape(s.depth)[0] for s in sources), max(np.shape(s.depth)[1] for s in sources)
    if int(out_shape[0]) <= 0 or int(out_shape[1]) <= 0 or rows * width >= 2**_INDEX_BITS - 1:
        raise InputError(f"{label}: bad image sizes: sources {[np.shape(s.depth) for s in sources]}, target {tuple(out_shape)}")


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


class _Reads(NamedTuple):
    """Target pixels that read elsewhere than their point's own pixel would (footprints,
    filled holes), and where in the atlas."""

    pixels: np.ndarray
    read_x: np.ndarray
    read_y: np.ndarray


def _spread(
    cloud: _Cloud, winner: np.ndarray, covered: np.ndarray, front: np.ndarray, max_footprint: int, depth_tolerance: float
) -> tuple[np.ndarray | None, _Reads | None]:
    """Give the points their footprints (the module docstring); updates the arguments in place.

    Returns:
        for every target pixel, the flat index of the nearest pixel drawn on its own
        point (the hole filling reuses it), and where the footprint pixels read; None
        and None when nothing is drawn.
    """
    assert cloud.frames is not None
    frames = cloud.frames
    oh, ow = covered.shape
    # Empty pixels as farther than anything (a mask multiplies faster than it selects).
    depth = np.multiply(~covered, np.float32(_FAR), out=_SCRATCH.get("spread_depth", (oh, ow), np.float32))
    depth += front[: oh * ow].reshape(oh, ow)
    nearest_depth = cv2.erode(depth, np.ones((3, 3), np.uint8))
    nearest_depth *= np.float32(1.0 + depth_tolerance)
    drawn = depth <= nearest_depth  # not behind a neighbour...
    drawn &= covered  # ...and drawn
    if not drawn.any():
        return None, None
    nearest, distance = _nearest_drawn(drawn)
    asking = np.flatnonzero(~drawn)
    asking = asking[np.take(distance, asking) <= np.float32(max_footprint / 2)]
    point = np.take(winner, np.take(nearest, asking))
    col, row = _pixel_grid(oh, ow)
    col, row = np.take(col, asking), np.take(row, asking)
    joins, back_x, back_y = _in_footprint(cloud, point, col, row)
    # Steps across the source grid, towards where the pixel maps back, find the point
    # whose footprint it is where the nearest one's is not (Voronoi cells and footprints
    # differ where a surface is seen sheared), if a few steps can get there.
    with np.errstate(invalid="ignore"):
        reachable = np.maximum(np.abs(back_x), np.abs(back_y)) <= 1 + _STEPS
    reachable &= ~joins
    retry = np.flatnonzero(reachable)
    for _ in range(_STEPS):
        if not len(retry):
            break
        step_x, step_y = np.rint(back_x[retry]), np.rint(back_y[retry])
        np.clip(step_x, -1, 1, out=step_x)
        np.clip(step_y, -1, 1, out=step_y)
        step_y *= cloud.width
        step_y += step_x
        moved = point[retry] + step_y.astype(point.dtype)
        np.clip(moved, 0, cloud.size, out=moved)  # off the atlas: the sentinel, which has no frame
        point[retry] = moved
        found, back_x[retry], back_y[retry] = _in_footprint(cloud, moved, col[retry], row[retry])
        joins[retry] = found
        retry = retry[~found & (np.take(frames.reach, moved) > 0)]
    point_depth = _surface_depth(cloud, point, back_x, back_y)
    joins &= point_depth * np.float32(1.0 + depth_tolerance) < np.take(depth, asking)
    pixels, point, back_x, back_y = asking[joins], point[joins], back_x[joins], back_y[joins]
    winner[pixels] = point
    front[pixels] = point_depth[joins]
    covered.ravel()[pixels] = True
    atlas_col, atlas_row = _pixel_grid(cloud.rows[-1], cloud.width)
    _to_reads(back_x, back_y, np.take(frames.interior, point), np.take(atlas_col, point), np.take(atlas_row, point))
    return nearest, _Reads(pixels, back_x, back_y)


def _surface_depth(cloud: _Cloud, point: np.ndarray, back_x: np.ndarray, back_y: np.ndarray) -> np.ndarray:
    """The target depth of ``point``'s surface where a footprint pixel maps back to, ``(back_x, back_y)`` source
    pixels from it: its inverse depth extended to first order by the steps to its right and lower neighbours.

    A footprint pixel takes this depth rather than the point's own, so that on a surface seen
    steeply (its depth changing by more than ``depth_tolerance`` from pixel to pixel) a
    neighbour's footprint is not "nearer" than the pixel's own point, and neither displaces
    it nor hides it from ``visible``. Only framed points reach here, and a frame exists only
    where both neighbours are on the point's surface.
    """
    z = np.take(cloud.z, point)
    right = np.take(cloud.z, np.minimum(point + 1, cloud.size))
    down = np.take(cloud.z, np.minimum(point + cloud.width, cloud.size))
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / z
        surface = inverse + back_x * (1.0 / right - inverse) + back_y * (1.0 / down - inverse)
        # Where extending fails (a neighbour unknown, or a grazing surface extended past its
        # horizon), keep the point's own depth.
        return np.where(np.isfinite(surface) & (surface > 0), 1.0 / surface, z).astype(np.float32)


def _hole_reads(
    cloud: _Cloud, winner: np.ndarray, covered: np.ndarray, max_hole: int, nearest: np.ndarray | None
) -> _Reads | None:
    """Where the small holes (:func:`small_holes`) read: through the frame of the point drawn at the nearest drawn pixel."""
    assert cloud.frames is not None
    pixels = np.flatnonzero(small_holes(covered, max_hole))
    if not len(pixels) or not covered.any():
        return None
    if nearest is None:
        nearest = _nearest_drawn(covered)[0]
    point = np.take(winner, np.take(nearest, pixels))
    col, row = _pixel_grid(*covered.shape)
    read_x, read_y = _map_back(cloud, point, np.take(col, pixels), np.take(row, pixels))
    atlas_col, atlas_row = _pixel_grid(cloud.rows[-1], cloud.width)
    _to_reads(read_x, read_y, np.take(cloud.frames.interior, point), np.take(atlas_col, point), np.take(atlas_row, point))
    return _Reads(pixels, read_x, read_y)


def _in_footprint(
    cloud: _Cloud, point: np.ndarray, col: np.ndarray, row: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whether target pixels ``(col, row)`` are in ``point``'s footprint (within its :attr:`_Frames.reach`),
    and where they map back (:func:`_map_back`)."""
    assert cloud.frames is not None
    back_x, back_y = _map_back(cloud, point, col, row)
    distance = np.abs(back_x)
    np.maximum(distance, np.abs(back_y), out=distance)
    with np.errstate(invalid="ignore"):  # NaN: no frame, and no footprint
        inside = distance <= np.take(cloud.frames.reach, point)
    return inside, back_x, back_y


def _nearest_drawn(drawn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(H W,)`` each pixel's nearest ``drawn`` pixel (a flat index; itself if drawn), and the distance to it."""
    # The distance transform's labels number the zero (drawn) pixels in raster order.
    distance, labels = cv2.distanceTransformWithLabels(
        (~drawn).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5, labelType=cv2.DIST_LABEL_PIXEL
    )
    labels = labels.ravel()
    labels -= 1
    return np.take(np.flatnonzero(drawn), labels), distance.ravel()


def _remappable(images: list[np.ndarray]) -> bool:
    """Whether OpenCV's remap takes these images, stacked."""
    first = images[0]
    return (
        first.dtype in (np.uint8, np.uint16, np.int16, np.float32, np.float64)
        and (first.ndim == 2 or first.shape[2] <= 4)
        and sum(image.shape[0] for image in images) < _REMAP_LIMIT
        and max(image.shape[1] for image in images) < _REMAP_LIMIT
    )


def _resample_nearest(cloud: _Cloud, images: list[np.ndarray], winner: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Each target pixel takes its point's colour (the sentinel's: zero)."""
    atlas = cloud.atlas(images)
    channels = atlas.shape[2:]
    n = cloud.size
    pixels = _SCRATCH.get("pixels", (n + 1, *channels), atlas.dtype)
    pixels[:n] = atlas.reshape(n, *channels)
    pixels[n] = 0
    # mode="clip" skips the bounds checks and the buffering of `out` (indices are valid).
    return np.take(pixels, winner, axis=0, mode="clip").reshape(*shape, *channels)


def _resample_bilinear(
    cloud: _Cloud,
    images: list[np.ndarray],
    winner: np.ndarray,
    shape: tuple[int, int],
    reads: list[_Reads | None],
    own: np.ndarray | None,
) -> np.ndarray:
    """Each target pixel's colour, read bilinearly where it maps back to in its point's source.

    One ``cv2.remap`` of the atlas. A pixel drawn on its point's own pixel reads where
    the point's frame says (:class:`_Frames`), the pixels of ``reads`` where they say;
    with ``own`` (each point's own pixel: squares were drawn), a pixel drawn by another's
    square maps back on its own. An empty pixel reads far off the atlas, and so zero.
    """
    assert cloud.frames is not None
    frames = cloud.frames
    oh, ow = shape
    map_x = np.take(frames.read_x, winner, out=_SCRATCH.get("map_x", oh * ow, np.float32), mode="clip")
    map_y = np.take(frames.read_y, winner, out=_SCRATCH.get("map_y", oh * ow, np.float32), mode="clip")
    if own is not None:
        elsewhere = np.take(own, winner, mode="clip") != _arange(oh * ow)
        elsewhere &= winner < cloud.size
        pixels = np.flatnonzero(elsewhere)
        point = winner[pixels]
        col, row = _pixel_grid(oh, ow)
        read_x, read_y = _map_back(cloud, point, col[pixels], row[pixels])
        atlas_col, atlas_row = _pixel_grid(cloud.rows[-1], cloud.width)
        _to_reads(read_x, read_y, np.take(frames.interior, point), np.take(atlas_col, point), np.take(atlas_row, point))
        map_x[pixels], map_y[pixels] = read_x, read_y
    for given in reads:
        if given is not None:
            map_x[given.pixels], map_y[given.pixels] = given.read_x, given.read_y
    atlas = cloud.atlas(images)
    out = cv2.remap(atlas, map_x.reshape(oh, ow), map_y.reshape(oh, ow), cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return out.reshape(oh, ow, *atlas.shape[2:])


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
    return _fill(image, covered, method, max_hole, None)


def _fill(image: np.ndarray, covered: np.ndarray, method: HoleFill, max_hole: int, nearest: np.ndarray | None) -> np.ndarray:
    """:func:`fill_holes`, with the nearest covered pixel of every pixel if known already."""
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
    if nearest is None:
        nearest = _nearest_drawn(covered)[0]
    hole_index = np.flatnonzero(holes)
    out = image.copy()
    flat = out.reshape(covered.size, -1)
    flat[hole_index] = np.take(flat, np.take(nearest, hole_index), axis=0)
    return out
