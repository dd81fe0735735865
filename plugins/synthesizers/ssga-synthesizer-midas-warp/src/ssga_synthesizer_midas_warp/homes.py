"""RGB-D views of procedural homes the benchmark never evaluates: for training, calibration and held-out figures.

The benchmark evaluates procedural seeds 0, 1 and 2 (the demo seed 0); the pnv
descriptor's weights used 1000-1007 and 1100-1101. Here: training on
:data:`TRAIN_SEEDS`, calibration on :data:`CALIBRATION_SEEDS`, held-out figures on
:data:`HELDOUT_SEEDS`, three disjoint sets. Even seeds are built with the benchmark's
home settings (8 rooms, 18 x 14 m), odd seeds with the procedural source's defaults
(4 rooms, 12 x 10 m, the demo's), so rooms of both sizes are seen. Poses are uniform
over each home's free floor with a uniform heading, at the workspace's camera height,
drawn from the seed: the same views every time.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ssga_core import View

TRAIN_SEEDS: tuple[int, ...] = tuple(range(2000, 2012))
CALIBRATION_SEEDS: tuple[int, ...] = (2100, 2101, 2102, 2103)
HELDOUT_SEEDS: tuple[int, ...] = (2200, 2201, 2202, 2203)

BENCH_HOME = {"rooms": 8, "home_width": 18.0, "home_depth": 14.0}
"""The benchmark's home settings (``ssga_bench/configs/bench.toml``)."""
DEMO_HOME = {"rooms": 4, "home_width": 12.0, "home_depth": 10.0}
"""The procedural source's defaults, the demo's."""


def home_settings(seed: int) -> dict[str, float]:
    return BENCH_HOME if seed % 2 == 0 else DEMO_HOME


@dataclass
class Views:
    """``rgb`` ``(N, H, W, 3)`` uint8, ``depth`` ``(N, H, W)`` float32 planar metres, ``poses`` ``(N, 3)`` (x, y, yaw), ``home`` ``(N,)`` seeds."""

    rgb: np.ndarray
    depth: np.ndarray
    poses: np.ndarray
    home: np.ndarray

    def __len__(self) -> int:
        return len(self.rgb)

    @classmethod
    def concat(cls, parts: Sequence[Views]) -> Views:
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("rgb", "depth", "poses", "home")))

    def save(self, path: Path) -> None:
        """As ``.npz`` (depth as float16), written whole or not at all."""
        tmp = path.with_name(path.stem + ".tmp.npz")
        np.savez(tmp, rgb=self.rgb, depth=self.depth.astype(np.float16), poses=self.poses, home=self.home)
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> Views:
        with np.load(path, allow_pickle=False) as f:
            return cls(f["rgb"], f["depth"].astype(np.float32), f["poses"], f["home"])


def open_home(seed: int):  # -> ssga_bench.Workspace
    """The procedural home ``seed`` with :func:`home_settings` (through the installed registry)."""
    from ssga_core import resolve_stage
    from ssga_core.cli import current_registry

    return resolve_stage("workspace", {"name": "procedural", "seed": seed, **home_settings(seed)}, current_registry()).create().open()


def standing_views(seed: int, count: int, *, progress: Callable[[str], None] | None = None) -> Iterator[View]:
    """``count`` rendered views of home ``seed`` (RGB, depth and semantic ids) from random
    standing poses drawn from the seed: the same views every time. Other plugins' training
    commands render their views here too."""
    from ssga_core import Pose

    workspace = open_home(seed)
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


def render_views(seed: int, count: int, *, progress: Callable[[str], None] | None = None) -> Views:
    """``count`` RGB-D views of home ``seed`` from random standing poses (:func:`standing_views`)."""
    rgb, depth, poses = [], [], []
    for view in standing_views(seed, count, progress=progress):
        assert view.depth is not None
        rgb.append(view.rgb)
        depth.append(view.depth.astype(np.float32))
        poses.append((view.pose.x, view.pose.y, view.pose.yaw))
    return Views(np.stack(rgb), np.stack(depth), np.asarray(poses, dtype=np.float64), np.full(count, seed, dtype=np.int64))


def cached_views(folder: Path, seeds: Sequence[int], per_home: int, progress: Callable[[str], None] | None = None) -> Views:
    """:func:`render_views` of every seed, each cached in ``folder`` as ``views-<seed>-<per_home>.npz``."""
    folder.mkdir(parents=True, exist_ok=True)
    parts = []
    for seed in seeds:
        path = folder / f"views-{seed}-{per_home}.npz"
        if not path.is_file():
            render_views(seed, per_home, progress=progress).save(path)
            if progress:
                progress(f"home {seed}: {per_home} views rendered into {path}")
        parts.append(Views.load(path))
    return Views.concat(parts)
