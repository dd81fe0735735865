"""The ``depth-warp`` synthesizer: a thin adapter from ssga's views and poses to :func:`forward_warp_many`."""

from __future__ import annotations

import threading
import weakref
from collections.abc import Sequence
from typing import Literal

import numpy as np
from pydantic import Field

from ssga_core import Data, Pose, StageConfig, Synthesis, Synthesizer, View, hookimpl
from ssga_synthesizer_depth_warp.layout import layout_fill
from ssga_synthesizer_depth_warp.warp import Source, forward_warp_many, small_holes, surface_links


class DepthWarpConfig(StageConfig):
    """How the point cloud is splatted into the target view.

    The defaults are the best measured by ``scripts/synthesis_quality.py`` on the demo
    workspace within the speed budget (about twice the 0.1 warp's time); figures are
    PSNR / SSIM against true renders on the content the source saw (the README has them all).
    """

    splat: int = Field(
        default=1,
        ge=1,
        le=4,
        description="Side of a square every point draws as well, in pixels: 1 its nearest pixel only, 2 the "
        "2 x 2 pixels around it, 3 a 3 x 3 block. 2 closes the cracks of forward moves (29.7 dB on the demo, as "
        "hole filling does) but fattens foreground edges (Middlebury: 26.0 dB against 27.4) and takes 30% "
        "longer: 1 by default.",
    )
    footprint: Literal["adaptive", "square"] = Field(
        default="adaptive",
        description="'square': a point draws the 'splat' square; 'adaptive': it also covers the target pixels "
        "its source pixel spreads over (the warp's local Jacobian), never across a depth edge, so surfaces seen "
        "magnified stay closed and hide what is behind them. Adaptive is the better render (29.9 dB against 29.7 "
        "from one view; from all four demo views 98.8% of the seen content covered at 24.1 dB, against 93.5% at "
        "17.8 dB). Its warp takes 2 to 3 times the square's, which is 5% of the demo's time (4.6 s against "
        "4.3 s of 91 s), so it is the default; preset 'square' for the faster one.",
    )
    max_footprint: int = Field(
        default=32,
        ge=1,
        le=256,
        description="An adaptive footprint reaches at most half this many pixels from a drawn pixel; content "
        "seen magnified more opens cracks. 32 covers a far view's floor seen from nearby: 16 left 1.2% more of "
        "the seen content empty and cost 2.3 dB on it (four demo views fused); 64 gained 0.7 dB there.",
    )
    resample: Literal["bilinear", "nearest"] = Field(
        default="bilinear",
        description="Colour of a drawn (or filled) pixel: 'bilinear' reads the source where the pixel's centre "
        "maps back to, never across a depth edge; 'nearest' copies its point's colour, up to 0.7 px off (the 0.1 "
        "warp). Bilinear: 29.7 dB / 0.806 against 28.0 / 0.764 from one demo view; 27.4 against 26.9 dB on "
        "Middlebury.",
    )
    depth_edge: float = Field(
        default=0.03,
        gt=0.0,
        le=1.0,
        description="Two neighbouring source pixels are on different surfaces where their inverse depths differ "
        "by more than this (relative) and by that much more than a neighbouring step (a floor seen at a grazing "
        "angle stays one surface); no bilinear read or footprint spans such an edge. 0.03 measured best on the "
        "demo (0.01: -0.1 dB); on Middlebury, adaptive footprints across edges (1.0) add pixels at 17.8 dB "
        "where 0.03 adds them at 22.6.",
    )
    fill_holes: Literal["none", "inpaint", "nearest"] = Field(
        default="nearest",
        description="Filling of small holes in the synthetic image: 'none' leaves them black, 'inpaint' uses "
        "OpenCV's Telea inpainting, 'nearest' takes the surface of the nearest drawn pixel: with bilinear "
        "resampling it reads the source where the hole maps back through that pixel's point (cracks get their "
        "true colour), else it copies that pixel's colour. Filled pixels keep depth 0 (unknown). From one demo "
        "view, max_hole 8: nearest 29.5 dB, inpaint 29.2, none 11.0 (the cracks of forward moves stay black).",
    )
    max_hole: int = Field(
        default=16,
        ge=2,
        le=256,
        description="Holes narrower than this many pixels are filled; wider ones (large disocclusions, the "
        "part of the target the source never saw) stay black. 16 measured best on the seen content (29.7 dB; "
        "8: 29.5, 4: 26.0 as cracks stay open; 32: 29.7 while painting more of what no source saw).",
    )
    fill_unseen: Literal["none", "layout"] = Field(
        default="none",
        description="What fills the holes left after 'fill_holes' (what no source saw): 'none' leaves them "
        "black; 'layout' draws them as the room's floor, walls and ceiling, placed by the sources' own points "
        "and textured from them (ssga_synthesizer_depth_warp.layout). Filled pixels get the layout's depth.",
    )
    wall_band: float = Field(
        default=0.45,
        gt=0.05,
        le=2.0,
        description="With fill_unseen = 'layout': the band of wall (metres below the ceiling) whose points place "
        "the walls and give their texture: above doors and furniture.",
    )
    max_depth: float = Field(
        default=50.0,
        gt=0.0,
        description="Source points farther than this (metres) are ignored, as if their depth were unknown.",
    )


class DepthWarp(Synthesizer):
    """Unprojects the view's metric depth into a point cloud and renders it at the target pose.

    The paper's scene synthesis (§3.1.3) with the depth the view carries (a workspace's
    depth sensor, or a monocular estimate stored as depth): a pinhole-model point cloud,
    forward-splatted with a z-buffer into the same camera at the target pose. Several
    views render jointly: their points share one z-buffer.
    """

    name = "depth-warp"
    abbrev = "DW"
    Config = DepthWarpConfig
    consumes = frozenset({Data.RGB, Data.DEPTH})
    produces = frozenset({Data.RGB, Data.DEPTH, Data.POINT_MAP})
    presets = {
        "raw": {"fill_holes": "none"},
        "closed": {"splat": 2},
        "square": {"footprint": "square"},
        "v0.1": {"footprint": "square", "resample": "nearest", "max_hole": 8},
    }

    def __init__(self, config: DepthWarpConfig | None = None) -> None:
        super().__init__(config)
        # A view's surface links depend on its depth alone, and the pipeline renders each
        # real view at many targets: compute them once per View object (views are frozen).
        self._links: weakref.WeakKeyDictionary[View, np.ndarray] = weakref.WeakKeyDictionary()
        self._lock = threading.Lock()

    def _synthesize(self, view: View, target: Pose) -> Synthesis:
        return self._synthesize_from([view], target)[0]

    def _synthesize_from(self, views: Sequence[View], target: Pose) -> list[Synthesis]:
        """All the views' points in one z-buffer, seen by the first view's camera at ``target``."""
        config: DepthWarpConfig = self.config  # type: ignore[assignment]
        camera = views[0].camera
        needs_links = config.footprint == "adaptive" or config.resample == "bilinear"
        sources = []
        for view in views:
            assert view.depth is not None  # the base class refuses views without depth
            links = self._surface_links(view) if needs_links else None
            sources.append(Source(view.rgb, view.depth, view.camera.K, target.relative_to(view.pose), links))
        warps = forward_warp_many(
            sources,
            camera.K,
            camera.shape,
            splat=config.splat,
            footprint=config.footprint,
            max_footprint=config.max_footprint,
            resample=config.resample,
            depth_edge=config.depth_edge,
            max_depth=config.max_depth,
            fill=config.fill_holes,
            max_hole=config.max_hole,
        )
        rgb, depth = warps[0].rgb, warps[0].depth
        if config.fill_unseen == "layout":
            unseen = ~warps[0].covered
            if config.fill_holes != "none":
                unseen &= ~small_holes(warps[0].covered, config.max_hole)
            rgb, depth = layout_fill(rgb, depth, unseen, camera, target, views, wall_band=config.wall_band, max_depth=config.max_depth)
        # One synthetic view, the fused render, seen through each source's own point map.
        synthetic = View(rgb=rgb, pose=target, camera=camera, depth=depth, synthetic=True)
        return [Synthesis(view=synthetic, target_uv=w.target_uv, visible=w.visible) for w in warps]

    def _surface_links(self, view: View) -> np.ndarray:
        config: DepthWarpConfig = self.config  # type: ignore[assignment]
        with self._lock:
            links = self._links.get(view)
        if links is None:
            assert view.depth is not None
            links = surface_links(view.depth, config.depth_edge, config.max_depth)
            with self._lock:
                self._links[view] = links
        return links


@hookimpl
def ssga_register_synthesizers() -> list[type[Synthesizer]]:
    return [DepthWarp]
