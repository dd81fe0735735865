"""The oracle synthesizer: true renders of the workspace in place of synthetic views.

A report's oracle row trains a variant exactly as the method does, at the same poses,
but its "synthetic" views are what the camera would really see there. The gap between
the oracle row and the variant's own row is what synthesis costs; the gap between the
oracle and 100 is what the descriptor, parser and classifier cost. Only a workspace
that renders any pose (not a captured one) has an oracle.

The point map is exact too: each source pixel is unprojected with its true depth and
projected into the target camera, and it is visible where it lands on the surface the
true render shows there (within 2 % of its depth).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ssga_core.data import Data, Synthesis, View
from ssga_core.geometry import Pose
from ssga_core.stages import Synthesizer
from ssga_bench.workspace import Workspace

_DEPTH_TOLERANCE = 0.02


class TrueRender(Synthesizer):
    """Renders the target pose with the workspace itself (an oracle, never a method)."""

    name = "true-render"
    abbrev = "TRUE"
    consumes = frozenset({Data.RGB, Data.DEPTH})
    produces = frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC, Data.POINT_MAP})

    def __init__(self, workspace: Workspace) -> None:
        super().__init__()
        self.workspace = workspace

    def _synthesize(self, view: View, target: Pose) -> Synthesis:
        return point_map(view, self._render(target))

    def _synthesize_from(self, views: Sequence[View], target: Pose) -> list[Synthesis]:
        truth = self._render(target)  # one render serves every source
        return [point_map(view, truth) for view in views]

    def _render(self, target: Pose) -> View:
        return dataclasses.replace(self.workspace.render(target), synthetic=True)


def point_map(source: View, truth: View) -> Synthesis:
    """Where each pixel of ``source`` lands in ``truth`` (a render at another pose), and whether it is seen there."""
    assert source.depth is not None and truth.depth is not None
    depth = np.where(np.isfinite(source.depth) & (source.depth > 0), source.depth, np.nan).astype(np.float32)
    world = source.pose.to_world(source.camera.unproject(depth).reshape(-1, 3))
    uv, z = truth.camera.project(truth.pose.to_camera(world))
    uv = uv.reshape(*depth.shape, 2).astype(np.float32)
    z = z.reshape(depth.shape)
    inside = truth.camera.contains(uv)
    h, w = truth.camera.shape
    col = np.clip(np.rint(np.nan_to_num(uv[..., 0])), 0, w - 1).astype(np.intp)
    row = np.clip(np.rint(np.nan_to_num(uv[..., 1])), 0, h - 1).astype(np.intp)
    seen = truth.depth[row, col]
    with np.errstate(invalid="ignore"):
        visible = inside & (np.abs(z - seen) <= _DEPTH_TOLERANCE * z)
    return Synthesis(view=truth, target_uv=uv, visible=visible)
