"""Forward warping of images with per-pixel depth into another pinhole camera.

The warp's entry points (:func:`forward_warp`, :func:`forward_warp_many`), composed of
one module per step, each with the why of its step in its docstring:

* :mod:`.projection`: where every source pixel lands in the target camera (:func:`reproject`);
* :mod:`.surface`: which neighbouring source pixels lie on one surface (:func:`surface_links`);
* :mod:`.frames`: each point's local frame, the warp's Jacobian there;
* :mod:`.cloud`: all the sources' points, numbered in one atlas (:class:`Source`);
* :mod:`.zbuffer`: the z-buffer, and the ``splat`` squares;
* :mod:`.footprints`: the adaptive footprints (``footprint="adaptive"``);
* :mod:`.resample`: each drawn pixel's colour (``resample``);
* :mod:`.holes`: hole filling (:func:`fill_holes`, :func:`small_holes`);
* :mod:`.scratch`: the per-thread scratch arrays they share.

Everything the package exports is importable from here, as it was before the steps
moved out to their modules.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, TypedDict, Unpack

import numpy as np

from ssga_core import InputError
from ssga_synthesizer_depth_warp.cloud import Source, _move
from ssga_synthesizer_depth_warp.footprints import _spread
from ssga_synthesizer_depth_warp.holes import HOLE_FILLS, HoleFill, _fill, fill_holes, small_holes  # noqa: F401 (re-exported)
from ssga_synthesizer_depth_warp.projection import reproject  # noqa: F401 (re-exported)
from ssga_synthesizer_depth_warp.resample import _hole_reads, _remappable, _resample_bilinear, _resample_nearest
from ssga_synthesizer_depth_warp.scratch import _SCRATCH
from ssga_synthesizer_depth_warp.surface import INTERIOR, LINKED_DOWN, LINKED_RIGHT, surface_links  # noqa: F401 (re-exported)
from ssga_synthesizer_depth_warp.zbuffer import _INDEX_BITS, _zbuffer

Footprint = Literal["adaptive", "square"]
Resample = Literal["bilinear", "nearest"]


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


class WarpOptions(TypedDict, total=False):
    """The keyword options of :func:`forward_warp`, passed on as they are to :func:`forward_warp_many`,
    which documents them and gives their defaults."""

    splat: int
    footprint: Footprint
    max_footprint: int
    resample: Resample
    depth_edge: float
    max_depth: float
    fill: HoleFill
    max_hole: int
    depth_tolerance: float


def forward_warp(
    rgb: np.ndarray,
    depth: np.ndarray,
    K_src: np.ndarray,
    K_dst: np.ndarray,
    T_dst_from_src: np.ndarray,
    out_shape: tuple[int, int] | None = None,
    **options: Unpack[WarpOptions],
) -> Warp:
    """Render ``rgb`` seen with ``depth`` from the source camera into the target camera.

    Args:
        rgb: ``(H, W)`` or ``(H, W, C)`` source image, any dtype (hole filling needs
            uint8 with 1 or 3 channels).
        depth: ``(H, W)`` source planar depths (unknown: ``<= 0`` or non-finite).
        K_src, K_dst: ``3 x 3`` pinhole intrinsics of the two cameras.
        T_dst_from_src: ``4 x 4`` transform from the source camera frame to the target's.
        out_shape: ``(H', W')`` of the target image; the source's if omitted.
        **options: ``splat``, ``footprint``, ``max_footprint``, ``resample``, ``depth_edge``,
            ``max_depth``, ``fill``, ``max_hole``, ``depth_tolerance``: as for
            :func:`forward_warp_many`, with its defaults.

    Returns:
        the :class:`Warp`.
    """
    out_shape = np.shape(depth)[:2] if out_shape is None else out_shape
    return forward_warp_many([Source(rgb, depth, K_src, T_dst_from_src)], K_dst, out_shape, **options)[0]  # type: ignore[arg-type]


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
            pixels spread over (:mod:`.footprints`), so surfaces seen magnified stay
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
