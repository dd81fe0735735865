"""Views of procedural homes for training and held-out evaluation, with pose-derived relations.

A *place* is an anchor pose, drawn uniformly over a home's free floor with a uniform
heading, and ``views_per_place - 1`` more poses jittered around it (within
``jitter_m`` and ``jitter_deg``). As NetVLAD derives its training pairs from GPS, two
views are *positives* when they stand close in position and heading, and *negatives*
when they are far apart in either, or in different homes; pairs in between are
neither. Homes are procedural ones with the benchmark's settings (8 rooms, 18 x 14 m),
on seeds no other plugin uses (:mod:`ssga_workspace_procedural.training_homes`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ssga_bench import ArrayRecord

@dataclass
class Places(ArrayRecord):
    """Views of places: ``rgb`` ``(N, S, S, 3)`` uint8, ``poses`` ``(N, 3)`` (x, y, yaw),
    ``home`` ``(N,)`` seeds, ``place`` ``(N,)`` place ids; a place's views are consecutive."""

    rgb: np.ndarray
    poses: np.ndarray
    home: np.ndarray
    place: np.ndarray


def render_places(
    seed: int,
    places: int,
    *,
    views_per_place: int = 2,
    jitter_m: float = 0.5,
    jitter_deg: float = 20.0,
    first_place: int = 0,
    progress: Callable[[str], None] | None = None,
) -> Places:
    """``places`` places of home ``seed`` (poses drawn with the home's seed: the same every time)."""
    from ssga_workspace_procedural.training_homes import open_home

    from ssga_core import Pose

    workspace = open_home(seed)
    plan = workspace.floor_plan
    xmin, ymin, xmax, ymax = plan.bounds
    rng = np.random.default_rng([seed, places, views_per_place])

    def stand() -> tuple[float, float]:
        while True:
            x, y = rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)
            if plan.can_stand(x, y):
                return x, y

    poses = []
    for _ in range(places):
        x, y = stand()
        yaw = rng.uniform(-math.pi, math.pi)
        poses.append((x, y, yaw))
        for _ in range(views_per_place - 1):
            for _ in range(100):
                r, a = jitter_m * math.sqrt(rng.uniform()), rng.uniform(-math.pi, math.pi)
                jx, jy = x + r * math.cos(a), y + r * math.sin(a)
                if plan.can_stand(jx, jy):
                    break
            else:
                jx, jy = x, y
            poses.append((jx, jy, _wrap(yaw + math.radians(rng.uniform(-jitter_deg, jitter_deg)))))
    rgb = np.empty((len(poses), *workspace.camera.shape, 3), dtype=np.uint8)
    for i, (x, y, yaw) in enumerate(poses):
        rgb[i] = workspace.render(Pose(x, y, yaw, workspace.camera_height)).rgb
        if progress and (i + 1) % 100 == 0:
            progress(f"home {seed}: rendered {i + 1}/{len(poses)} views")
    return Places(
        rgb=rgb,
        poses=np.asarray(poses, dtype=np.float64),
        home=np.full(len(poses), seed, dtype=np.int64),
        place=np.repeat(np.arange(first_place, first_place + places), views_per_place),
    )


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def relations(
    poses_a: np.ndarray,
    home_a: np.ndarray,
    poses_b: np.ndarray,
    home_b: np.ndarray,
    *,
    positive_m: float,
    positive_deg: float,
    negative_m: float,
    negative_deg: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``(positive, negative)`` boolean ``(A, B)`` masks between two sets of views.

    Positive: same home, within ``positive_m`` and ``positive_deg``. Negative: another
    home, or farther than ``negative_m``, or headings more than ``negative_deg`` apart.
    """
    same = home_a[:, None] == home_b[None, :]
    dist = np.hypot(poses_a[:, None, 0] - poses_b[None, :, 0], poses_a[:, None, 1] - poses_b[None, :, 1])
    turn = np.abs((poses_a[:, None, 2] - poses_b[None, :, 2] + np.pi) % (2 * np.pi) - np.pi)
    positive = same & (dist <= positive_m) & (turn <= math.radians(positive_deg))
    negative = ~same | (dist > negative_m) | (turn > math.radians(negative_deg))
    return positive, negative
