"""What a protocol's plan is made of: the grid of location cells, the samples (each
viewpoint with its class and, for a test view, its view overlap and difficulty level) and
the plan that holds them (:mod:`ssga_bench.protocol` draws it)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ssga_core.geometry import Pose
from ssga_bench.protocol_config import ProtocolConfig

Split = Literal["train", "target", "test", "val"]


@dataclass(frozen=True)
class Grid:
    """The grid of location cells: cell ``(i, j)`` has index ``j * nx + i``."""

    x0: float
    y0: float
    cell_size: float
    nx: int
    ny: int

    @classmethod
    def covering(cls, bounds: tuple[float, float, float, float], cell_size: float) -> Grid:
        xmin, ymin, xmax, ymax = bounds
        x0, y0 = math.floor(xmin / cell_size) * cell_size, math.floor(ymin / cell_size) * cell_size
        return cls(x0, y0, cell_size, max(1, math.ceil((xmax - x0) / cell_size)), max(1, math.ceil((ymax - y0) / cell_size)))

    def centroids(self) -> np.ndarray:
        """``(nx * ny, 2)`` cell centroids by cell index."""
        j, i = np.divmod(np.arange(self.nx * self.ny), self.nx)
        return np.stack([self.x0 + (i + 0.5) * self.cell_size, self.y0 + (j + 0.5) * self.cell_size], axis=-1)

    def box(self, cell: int) -> tuple[float, float, float, float]:
        j, i = divmod(cell, self.nx)
        x, y = self.x0 + i * self.cell_size, self.y0 + j * self.cell_size
        return (x, y, x + self.cell_size, y + self.cell_size)


@dataclass(frozen=True)
class Sample:
    """One viewpoint of the benchmark: a real training view, a synthesis target or a test view."""

    id: str
    split: Split
    place: int
    """Class index, ``cell_rank * orientations + orientation``."""
    cell: int
    """Grid-cell index."""
    orientation: int
    pose: Pose
    vo: float | None = None
    """Test views: view overlap (%) with the class's training viewpoint."""
    vo_landmark: float | None = None
    """Test views: view overlap (%) with the cell's real training view."""
    level: int | None = None
    """Test views: difficulty level 1, 2 or 3."""
    source: int | None = None
    """For a captured workspace: the index of the captured view this sample is."""


@dataclass(frozen=True)
class Plan:
    """Every viewpoint of a benchmark workspace, before anything is rendered."""

    workspace: str
    config: ProtocolConfig
    grid: Grid
    cells: tuple[int, ...]
    """Selected grid cells, in class order."""
    samples: tuple[Sample, ...]

    @property
    def num_classes(self) -> int:
        return len(self.cells) * self.config.orientations

    def split(self, split: Split) -> list[Sample]:
        return [s for s in self.samples if s.split == split]

    def level_counts(self) -> dict[int, int]:
        counts = {1: 0, 2: 0, 3: 0}
        for s in self.split("test"):
            counts[s.level] += 1  # type: ignore[index]
        return counts


def capture_height(captures: Sequence[Pose]) -> float:
    """The height a captured workspace's views are planned at: its captures' median (1.5 m without any)."""
    return float(np.median([p.height for p in captures])) if len(captures) else 1.5


def level_of(vo: float, bounds: tuple[float, float] = (60.0, 30.0)) -> int:
    """Difficulty level of a view overlap: 1 above ``bounds[0]``, 2 above ``bounds[1]``, else 3."""
    return 1 if vo > bounds[0] else 2 if vo > bounds[1] else 3
