"""Labelled views of procedural homes the benchmark never evaluates: for training and held-out figures.

The benchmark evaluates procedural seeds 0, 1 and 2; the other learned plugins' weights
used 1000-1101 (pnv), 2000-2203 (midas-warp) and 3000-3005 (synsin). Here: training on
:data:`TRAIN_SEEDS` (4000-4011), held-out figures on :data:`HELDOUT_SEEDS`
(4100-4103). Views are
:func:`~ssga_workspace_procedural.training_homes.standing_views` (uniform standing
poses and headings drawn from the seed; even seeds with the benchmark's home settings,
odd ones with the demo's), and their semantic ids become class indices: procedural id
``k + 1`` is class ``k`` (:data:`~.classes.PROCEDURAL`), unknown pixels ``-1``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ssga_bench import ArrayRecord, cached_homes

TRAIN_SEEDS: tuple[int, ...] = tuple(range(4000, 4012))
HELDOUT_SEEDS: tuple[int, ...] = (4100, 4101, 4102, 4103)


@dataclass
class Labelled(ArrayRecord):
    """``rgb`` ``(N, H, W, 3)`` uint8, ``labels`` ``(N, H, W)`` int8 class indices (``-1`` unknown), ``home`` ``(N,)`` seeds."""

    rgb: np.ndarray
    labels: np.ndarray
    home: np.ndarray


def class_labels(semantic: np.ndarray) -> np.ndarray:
    """Procedural semantic ids to class indices (id ``k + 1`` -> ``k``; unknown and id 0 -> ``-1``)."""
    return np.where(semantic > 0, semantic - 1, -1).astype(np.int8)


def render_labelled(seed: int, count: int, *, progress: Callable[[str], None] | None = None) -> Labelled:
    """``count`` views of home ``seed`` with their class labels (the same views every time)."""
    from ssga_workspace_procedural.training_homes import bench_and_demo_sized, standing_views

    rgb, labels = [], []
    for view in standing_views(seed, count, bench_and_demo_sized(seed), progress=progress):
        assert view.semantic is not None, "procedural views carry semantic ids"
        rgb.append(view.rgb)
        labels.append(class_labels(view.semantic))
    return Labelled(np.stack(rgb), np.stack(labels), np.full(count, seed, dtype=np.int64))


def cached_labelled(folder: Path, seeds: Sequence[int], per_home: int, progress: Callable[[str], None] | None = None) -> Labelled:
    """:func:`render_labelled` of every seed, each home rendered once into ``folder``."""
    from ssga_workspace_procedural.training_homes import RENDERER_VERSION

    settings = {"per_home": per_home, "renderer": RENDERER_VERSION}
    return cached_homes(folder, "labelled", seeds, settings, lambda seed: render_labelled(seed, per_home, progress=progress), Labelled, progress=progress)
