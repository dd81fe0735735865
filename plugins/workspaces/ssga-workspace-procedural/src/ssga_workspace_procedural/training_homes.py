"""Procedural homes for training learned plugins, and views of them from random standing poses.

The benchmark evaluates procedural seeds 0, 1 and 2 (the demo seed 0); every learned
plugin trains and reports held-out figures on seeds of 1000 and above, a range of its
own (pnv 1000-1101, midas-warp 2000-2203, synsin 3000-3101, cascade-seg 4000-4103), so
no plugin's weights have seen a home another plugin's figures come from. Each draws
its poses from the seed: the same views every time, on every machine.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ssga_bench import Workspace
    from ssga_core import View

RENDERER_VERSION = 1
"""Raise it when a change to the procedural homes or their renderer changes the pixels of a view:
the learned plugins' cached training views are keyed by it (:func:`ssga_bench.cached_homes`), and
are then rendered again instead of read back stale."""

BENCH_HOME: Mapping[str, Any] = {"rooms": 8, "home_width": 18.0, "home_depth": 14.0}
"""The benchmark's home settings (``ssga_bench/configs/bench.toml``)."""
DEMO_HOME: Mapping[str, Any] = {"rooms": 4, "home_width": 12.0, "home_depth": 10.0}
"""The demo's (``ssga_bench/configs/demo.toml``)."""


def bench_and_demo_sized(seed: int) -> Mapping[str, Any]:
    """Even seeds the benchmark's homes, odd seeds the demo's: training that sees both sizes."""
    return BENCH_HOME if seed % 2 == 0 else DEMO_HOME


def open_home(seed: int, settings: Mapping[str, Any] = BENCH_HOME) -> Workspace:
    """The procedural home ``seed`` with ``settings`` (the source's config fields)."""
    from ssga_workspace_procedural.plugin import ProceduralConfig, ProceduralWorkspaceSource

    return ProceduralWorkspaceSource(ProceduralConfig(seed=seed, **settings)).open()


def standing_views(seed: int, count: int, settings: Mapping[str, Any], *, progress: Callable[[str], None] | None = None) -> Iterator[View]:
    """``count`` rendered views (RGB, depth, semantic ids) of home ``seed`` from uniform standing
    positions on its free floor, with uniform headings, drawn from ``seed`` and ``count``."""
    from ssga_core import Pose

    workspace = open_home(seed, settings)
    plan = workspace.floor_plan
    xmin, ymin, xmax, ymax = plan.bounds
    rng = np.random.default_rng([seed, count, 7])
    i = 0
    while i < count:
        x, y = rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)
        if not plan.can_stand(x, y):
            continue
        yaw = rng.uniform(-np.pi, np.pi)
        yield workspace.render(Pose(x, y, yaw, workspace.camera_height))
        i += 1
        if progress and i % 100 == 0:
            progress(f"home {seed}: rendered {i}/{count} views")
