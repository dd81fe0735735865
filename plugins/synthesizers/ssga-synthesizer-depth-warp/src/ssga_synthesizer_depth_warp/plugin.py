"""The ``depth-warp`` synthesizer: a thin adapter from ssga's views and poses to :func:`forward_warp`."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from ssga_core import Data, Pose, StageConfig, Synthesis, Synthesizer, View, hookimpl
from ssga_synthesizer_depth_warp.warp import forward_warp


class DepthWarpConfig(StageConfig):
    """How the point cloud is splatted into the target view."""

    splat: int = Field(
        default=1,
        ge=1,
        le=4,
        description="Side of each point's square footprint in pixels: 1 draws its nearest pixel only, "
        "2 the 2 x 2 pixels around it, 3 a 3 x 3 block; larger footprints close the cracks that open "
        "when the camera moves closer to a surface, at the cost of fattened edges.",
    )
    fill_holes: Literal["none", "inpaint", "nearest"] = Field(
        default="nearest",
        description="Filling of small holes in the synthetic image: 'none' leaves them black, 'inpaint' uses "
        "OpenCV's Telea inpainting, 'nearest' copies the nearest drawn pixel (as good as 'inpaint' on the "
        "Middlebury check, and 5 to 50 times cheaper). Filled pixels keep depth 0 (unknown).",
    )
    max_hole: int = Field(
        default=8,
        ge=2,
        le=256,
        description="Holes narrower than this many pixels are filled; wider ones (large disocclusions, "
        "the part of the target the source never saw) stay black.",
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
    forward-splatted with a z-buffer into the same camera at the target pose.
    """

    name = "depth-warp"
    abbrev = "DW"
    Config = DepthWarpConfig
    consumes = frozenset({Data.RGB, Data.DEPTH})
    produces = frozenset({Data.RGB, Data.DEPTH, Data.POINT_MAP})
    presets = {
        "raw": {"fill_holes": "none"},
        "closed": {"splat": 2},
    }

    def _synthesize(self, view: View, target: Pose) -> Synthesis:
        config: DepthWarpConfig = self.config  # type: ignore[assignment]
        assert view.depth is not None  # the base class refuses views without depth
        K = view.camera.K
        warp = forward_warp(
            view.rgb,
            view.depth,
            K,
            K,
            target.relative_to(view.pose),
            view.camera.shape,
            splat=config.splat,
            max_depth=config.max_depth,
            fill=config.fill_holes,
            max_hole=config.max_hole,
        )
        synthetic = View(rgb=warp.rgb, pose=target, camera=view.camera, depth=warp.depth, synthetic=True)
        return Synthesis(view=synthetic, target_uv=warp.target_uv, visible=warp.visible)


@hookimpl
def ssga_register_synthesizers() -> list[type[Synthesizer]]:
    return [DepthWarp]
