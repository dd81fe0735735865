"""RGB-D views of procedural homes the benchmark never evaluates: for training, calibration and held-out figures.

Training on :data:`TRAIN_SEEDS`, calibration on :data:`CALIBRATION_SEEDS`, held-out
figures on :data:`HELDOUT_SEEDS`, three disjoint sets of the seeds no other plugin uses
(:mod:`ssga_workspace_procedural.training_homes`). Even seeds are built with the
benchmark's home settings (8 rooms, 18 x 14 m), odd seeds with the demo's (4 rooms,
12 x 10 m), so rooms of both sizes are seen; the views are
:func:`~ssga_workspace_procedural.training_homes.standing_views`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ssga_bench import ArrayRecord, cached_homes

TRAIN_SEEDS: tuple[int, ...] = tuple(range(2000, 2012))
CALIBRATION_SEEDS: tuple[int, ...] = (2100, 2101, 2102, 2103)
HELDOUT_SEEDS: tuple[int, ...] = (2200, 2201, 2202, 2203)


@dataclass
class Views(ArrayRecord):
    """``rgb`` ``(N, H, W, 3)`` uint8, ``depth`` ``(N, H, W)`` float32 planar metres, ``poses`` ``(N, 3)`` (x, y, yaw), ``home`` ``(N,)`` seeds."""

    stored = {"depth": np.float16}
    loaded = {"depth": np.float32}

    rgb: np.ndarray
    depth: np.ndarray
    poses: np.ndarray
    home: np.ndarray


def render_views(seed: int, count: int, *, progress: Callable[[str], None] | None = None) -> Views:
    """``count`` RGB-D views of home ``seed`` from random standing poses."""
    from ssga_workspace_procedural.training_homes import bench_and_demo_sized, standing_views

    rgb, depth, poses = [], [], []
    for view in standing_views(seed, count, bench_and_demo_sized(seed), progress=progress):
        assert view.depth is not None
        rgb.append(view.rgb)
        depth.append(view.depth.astype(np.float32))
        poses.append((view.pose.x, view.pose.y, view.pose.yaw))
    return Views(np.stack(rgb), np.stack(depth), np.asarray(poses, dtype=np.float64), np.full(count, seed, dtype=np.int64))


def cached_views(folder: Path, seeds: Sequence[int], per_home: int, progress: Callable[[str], None] | None = None) -> Views:
    """:func:`render_views` of every seed, each home rendered once into ``folder``."""
    from ssga_workspace_procedural.training_homes import RENDERER_VERSION

    settings = {"per_home": per_home, "renderer": RENDERER_VERSION}
    return cached_homes(folder, "views", seeds, settings, lambda seed: render_views(seed, per_home, progress=progress), Views, progress=progress)
