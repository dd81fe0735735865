"""View pairs of procedural homes, with true depth, for training and held-out evaluation.

A pair orbits a point, as the benchmark's synthesis does: the benchmark renders a
cell's one real view (1 m behind the cell centroid, looking at it) at the canonical
viewpoints of the cell's other heading classes (the same, 30 degrees apart). Here the
looked-at point is drawn uniformly over a home's free floor, the source stands
``distance`` (drawn in ``distance_m``) behind it along a uniform heading, and the target
stands as far behind it along a heading turned by up to ``max_turn_deg`` (SynSin's MP3D
data turns up to 45 degrees, ``--max_angle``); both must stand on free floor.

Homes are procedural ones with the benchmark's settings
(:func:`ssga_workspace_procedural.training_homes.open_home`), on seeds no other plugin
uses: this package trains on 3000-3005 and holds out 3100-3101.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ssga_bench import ArrayRecord

TRAIN_SEEDS = tuple(range(3000, 3006))
HELDOUT_SEEDS = (3100, 3101)


@dataclass
class Pairs(ArrayRecord):
    """``N`` pairs: ``rgb`` ``(N, 2, H, W, 3)`` uint8, ``depth`` ``(N, 2, H, W)`` float16 (metres),
    ``poses`` ``(N, 2, 3)`` (x, y, yaw), ``home`` ``(N,)`` seeds; index 0 of each pair is the source."""

    rgb: np.ndarray
    depth: np.ndarray
    poses: np.ndarray
    home: np.ndarray
    height: float = 1.5

    def pose(self, i: int, k: int):  # -> ssga_core.Pose
        from ssga_core import Pose

        x, y, yaw = self.poses[i, k]
        return Pose(float(x), float(y), float(yaw), self.height)


def orbit_poses(
    can_stand: Callable[[float, float], bool],
    bounds: tuple[float, float, float, float],
    count: int,
    rng: np.random.Generator,
    *,
    distance_m: tuple[float, float] = (0.6, 1.4),
    max_turn_deg: float = 60.0,
) -> np.ndarray:
    """``(count, 2, 3)`` source and target poses ``(x, y, yaw)`` orbiting points of the free floor."""
    xmin, ymin, xmax, ymax = bounds
    out = np.empty((count, 2, 3))
    made = 0
    for _ in range(count * 1000):
        if made == count:
            break
        cx, cy = rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)
        if not can_stand(cx, cy):
            continue
        d = rng.uniform(*distance_m)
        yaw = rng.uniform(-math.pi, math.pi)
        turn = math.radians(rng.uniform(-max_turn_deg, max_turn_deg))
        poses = []
        for heading in (yaw, yaw + turn):
            x, y = cx - d * math.cos(heading), cy - d * math.sin(heading)
            if not can_stand(x, y):
                break
            poses.append((x, y, _wrap(heading)))
        if len(poses) == 2:
            out[made] = poses
            made += 1
    if made < count:
        raise RuntimeError(f"only {made} of {count} orbit pairs fit on this floor")
    return out


def render_pairs(
    seed: int,
    count: int,
    *,
    distance_m: tuple[float, float] = (0.6, 1.4),
    max_turn_deg: float = 60.0,
    progress: Callable[[str], None] | None = None,
) -> Pairs:
    """``count`` orbit pairs of home ``seed`` (poses drawn from the seed: the same every time)."""
    from ssga_workspace_procedural.training_homes import open_home

    from ssga_core import Pose

    workspace = open_home(seed)
    plan = workspace.floor_plan
    rng = np.random.default_rng([seed, count, 7])
    poses = orbit_poses(plan.can_stand, plan.bounds, count, rng, distance_m=distance_m, max_turn_deg=max_turn_deg)
    h, w = workspace.camera.shape
    rgb = np.empty((count, 2, h, w, 3), dtype=np.uint8)
    depth = np.empty((count, 2, h, w), dtype=np.float16)
    for i in range(count):
        for k in range(2):
            x, y, yaw = poses[i, k]
            view = workspace.render(Pose(float(x), float(y), float(yaw), workspace.camera_height))
            rgb[i, k] = view.rgb
            assert view.depth is not None
            depth[i, k] = np.where(np.isfinite(view.depth), view.depth, 0.0)
        if progress and (i + 1) % 100 == 0:
            progress(f"home {seed}: rendered {i + 1}/{count} pairs")
    return Pairs(
        rgb=rgb, depth=depth, poses=poses, home=np.full(count, seed, dtype=np.int64), height=float(workspace.camera_height)
    )


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi
