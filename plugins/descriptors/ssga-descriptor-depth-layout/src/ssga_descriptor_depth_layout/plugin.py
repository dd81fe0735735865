"""The room's shape as a descriptor: where the image is near and where far, on a coarse grid.

GIST (``ssga-descriptor-gist``) reads the layout from the image's gradients, which a
pseudo-view drawn where no real view looked gets from textures the synthesizer guessed.
This one reads it from depth: the relative inverse depth MiDaS estimates from the RGB
(``midas-warp``'s network, the light one trained on procedural homes by default), so a
wall two metres away and one across the room differ whatever their texture.

* **depth**: the network's relative inverse depth of the image, from its RGB alone (a
  view's own depth, where it has one, is never read: a query is a camera image, and a
  pseudo-view must be described as a query would be);
* **grid**: area-averaged on a ``grid`` x ``grid`` grid, less its mean, L2-normalised: the
  cosine of two features is the correlation of their depth layouts, so neither the
  estimate's scale nor its shift, which one image cannot fix, counts (no calibration is
  used). A region's feature is the same of the region's box, cut from the whole image's
  estimate.
"""

from __future__ import annotations

from typing import Any, Literal

import cv2
import numpy as np
from pydantic import Field

from ssga_bench import Learned, LearnedConfig, network_field, weights_field
from ssga_core import CheckpointError, InputError, RegionDescriptor, Regions, View, box_pixels, hookimpl
from ssga_synthesizer_midas_warp.plugin import WEIGHTS_DIR, MidasWarp, MidasWarpConfig


class DepthLayoutConfig(LearnedConfig):
    weights: str = weights_field("midas-light.pt", "the official MiDaS v2.1 small file 'midas_v21_small_256.pt'", what="Depth network checkpoint (midas-warp's)")
    network: Literal["light", "v21-small"] | None = network_field("'light' (the packaged weights) or 'v21-small' (the official file's layout).")
    grid: int = Field(default=8, ge=1, description="Cells per side of the grid the estimated inverse depth is averaged on.")


class DepthLayout(Learned, RegionDescriptor):
    name = "depth-layout"
    abbrev = "DL"
    Config = DepthLayoutConfig
    reloaded = ("depth_network",)
    # midas-warp's files: a run on another workspace than procedural homes says the light network never saw its like.
    packaged_weights = WEIGHTS_DIR
    trained_on = MidasWarp.trained_on

    def _load(self) -> Any:
        cfg: DepthLayoutConfig = self.config  # type: ignore[assignment]
        # The synthesizer's loading (official and packaged layouts, strict, one line on a bad file, once
        # per process); no calibration: the feature, centred and unit-length, ignores the scale and shift it would fix.
        try:
            return MidasWarp(MidasWarpConfig(weights=cfg.weights, network=cfg.network, device=cfg.device, calibration="minmax"))
        except CheckpointError as error:  # the same line, naming this stage: its 'weights' field is the one to set
            raise type(error)(str(error).replace("synthesizer 'midas-warp'", f"{self.who} (midas-warp's network)", 1)) from None

    @property
    def dim(self) -> int:
        return self.config.grid**2

    def _describe(self, view: View, regions: Regions | None) -> np.ndarray:
        depth = self.inverse_depth(view.rgb)
        crops = [depth] + ([box_pixels(depth, box) for box in regions.boxes] if regions is not None else [])
        return np.stack([self.feature(crop) for crop in crops])

    def inverse_depth(self, rgb: np.ndarray) -> np.ndarray:
        """``(H, W)`` float32: the network's relative inverse depth of ``rgb`` (near is high; scale and shift unknown)."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise InputError(f"descriptor 'depth-layout': expected an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
        return self.depth_network.predict([rgb])[0].astype(np.float32)

    def feature(self, depth: np.ndarray) -> np.ndarray:
        """The ``(dim,)`` feature of an inverse depth map (or a box of one)."""
        g = self.config.grid
        cells = cv2.resize(depth, (g, g), interpolation=cv2.INTER_AREA).reshape(-1)
        centred = cells - cells.mean()
        norm = float(np.linalg.norm(centred))  # 0 for a flat estimate: zeros, whose cosine with any feature is 0
        return (centred / norm if norm > 0 else centred).astype(np.float32)


@hookimpl
def ssga_register_descriptors() -> list[type[RegionDescriptor]]:
    return [DepthLayout]
