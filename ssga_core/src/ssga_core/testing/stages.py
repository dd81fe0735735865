"""Stand-in stages: simple, exact and fast, to test one real stage in every variant order.

They are registered by no entry point; tests use them directly or register this module
on a fresh plugin manager.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydantic import Field

from ssga_core import hookimpl
from ssga_core.data import Data, LocalFeatures, Regions, Synthesis, View
from ssga_core.geometry import Pose
from ssga_core.stages import Descriptor, LocalDescriptor, Parser, RegionDescriptor, StageConfig, Synthesizer


class StripesConfig(StageConfig):
    stripes: int = Field(default=4, ge=1)


class StripesParser(Parser):
    """Vertical stripes of equal width."""

    name = "test-stripes"
    abbrev = "ST"
    Config = StripesConfig

    def _parse(self, view: View) -> Regions:
        h, w = view.camera.shape
        col = (np.arange(w) * self.config.stripes // w).astype(np.int32)
        return Regions.from_labels(np.broadcast_to(col, (h, w)))


def _grid_positions(view: View, n: int = 12) -> np.ndarray:
    h, w = view.camera.shape
    us = (np.arange(n) + 0.5) * w / n - 0.5
    vs = (np.arange(n) + 0.5) * h / n - 0.5
    uu, vv = np.meshgrid(us, vs)
    return np.stack([uu.ravel(), vv.ravel()], axis=-1).astype(np.float32)


class PatchColour(LocalDescriptor):
    """Mean colour of 144 patches on a 12 x 12 grid; a node's feature is the mean of its patches."""

    name = "test-patch-colour"
    abbrev = "PC"

    @property
    def dim(self) -> int:
        return 3

    def _extract(self, view: View) -> LocalFeatures:
        positions = _grid_positions(view)
        h, w = view.camera.shape
        r = max(1, w // 24)
        rgb = view.rgb.astype(np.float32) / 255.0
        desc = []
        for u, v in np.rint(positions).astype(int):
            desc.append(rgb[max(v - r, 0) : v + r + 1, max(u - r, 0) : u + r + 1].mean(axis=(0, 1)))
        return LocalFeatures(positions=positions, descriptors=np.asarray(desc, dtype=np.float32))

    def _pool(self, features: LocalFeatures, members: Sequence[np.ndarray]) -> np.ndarray:
        return np.stack([features.descriptors[m].mean(axis=0) if len(m) else np.zeros(3, np.float32) for m in members])


class RegionColour(RegionDescriptor):
    """Mean colour of the image and of each region's pixels (its box if no pixel is left)."""

    name = "test-region-colour"
    abbrev = "RC"

    @property
    def dim(self) -> int:
        return 3

    def _describe(self, view: View, regions: Regions | None) -> np.ndarray:
        rgb = view.rgb.astype(np.float32) / 255.0
        out = [rgb.mean(axis=(0, 1))]
        for k in range(len(regions) if regions is not None else 0):
            mask = regions.mask(k)
            if not mask.any():
                u0, v0, u1, v1 = np.rint(regions.boxes[k]).astype(int)
                mask = np.zeros(mask.shape, bool)
                mask[v0 : v1 + 1, u0 : u1 + 1] = True
            out.append(rgb[mask].mean(axis=0))
        return np.stack(out)


class ShiftWarp(Synthesizer):
    """Shifts the image by the parallax of the sideways move at the median depth.

    Exact for a camera moving sideways in front of a flat wall facing it (as in
    :func:`~ssga_core.testing.make_view`); it ignores turns, so it is no synthesizer
    for real use.
    """

    name = "test-shift"
    consumes = frozenset({Data.RGB, Data.DEPTH})
    produces = frozenset({Data.RGB, Data.DEPTH, Data.POINT_MAP})

    def _synthesize(self, view: View, target: Pose) -> Synthesis:
        camera = view.camera
        valid = view.valid_depth()
        depth = float(np.median(view.depth[valid])) if valid.any() else 1.0
        offset = target.to_camera(view.pose.position[None])[0] * -1.0  # target centre in the source frame
        du, dv = -camera.focal_px * offset[0] / depth, -camera.focal_px * offset[1] / depth
        target_uv = camera.pixel_grid() + np.array([du, dv], dtype=np.float32)
        target_uv[~valid] = np.nan
        visible = camera.contains(target_uv)
        rgb = np.zeros_like(view.rgb)
        out_depth = np.zeros(camera.shape, np.float32)
        t = np.rint(target_uv[visible]).astype(int)
        rgb[t[:, 1], t[:, 0]] = view.rgb[visible]
        out_depth[t[:, 1], t[:, 0]] = view.depth[visible]
        synthetic = View(rgb=rgb, pose=target, camera=camera, depth=out_depth, synthetic=True)
        return Synthesis(view=synthetic, target_uv=target_uv.astype(np.float32), visible=visible)


# The module itself is a plugin registering every stand-in: register it on a fresh plugin
# set in tests, or try the stand-ins from the command line with
# SSGA_PLUGIN_MODULES=ssga_core.testing.stages.


@hookimpl
def ssga_register_parsers() -> list[type[Parser]]:
    return [StripesParser]


@hookimpl
def ssga_register_descriptors() -> list[type[Descriptor]]:
    return [PatchColour, RegionColour]


@hookimpl
def ssga_register_synthesizers() -> list[type[Synthesizer]]:
    return [ShiftWarp]
