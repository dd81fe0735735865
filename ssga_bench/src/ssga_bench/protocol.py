"""The paper's benchmark protocol (§4.1-4.2), applied the same way to any workspace.

Definitions (the paper leaves the last three open; these are ssga's):

* **Cells.** The floor plan is cut into a grid of square location cells
  (``cell_size``, 2 m), aligned to multiples of the cell size.
* **Which cell a view belongs to.** A view belongs to a cell whose centroid lies in
  its visibility cone (the field-of-view wedge, cut by occluders, up to
  ``max_range``: :mod:`ssga_bench.visibility`); if several do, to the one whose
  centroid is nearest the viewpoint. A view whose cone holds no centroid belongs to
  no cell.
* **Place classes.** Each cell has ``orientations`` (12) classes, by the view's
  heading: class ``k`` covers headings within half a bin of ``k * 360 / 12`` degrees.
  ``cells`` (10) cells are drawn at random, giving 120 classes, numbered
  ``cell_rank * orientations + orientation``.
* **Training viewpoints.** The *canonical viewpoint* of a class looks at the cell
  centroid along the class heading from behind it, at the farthest free spot up to
  ``viewpoint_distance`` (1 m): the first of 100%, 75%, 50%, 25% and 12.5% of it
  (:data:`VIEWPOINT_STEPS`) that is free floor and from which the view belongs to the
  class. A cell is eligible only if all its classes have one. Cells whose viewpoints
  all stand at least half the distance back are drawn first; cells that need a nearer
  one (a small room, a cell by a wall) only when those are too few, so a floor plan
  with room for the full distance gets the protocol it always had. Each cell gets
  exactly one real training image, at the canonical viewpoint of one class drawn at
  random; the canonical viewpoints of its other classes are the *targets* the
  synthesizer renders the real image to.
* **When a floor plan has too few eligible cells**, the error names the values of
  ``cell_size`` and ``viewpoint_distance`` that would give enough
  (:func:`suggest`; ``ssga workspace build --suggest`` shows them all, with the
  ``test_radius`` the test views need).
* **Test views** are sampled independently: a position uniform in the free floor
  within ``test_radius`` of a selected cell's centroid and a uniform heading, kept
  if it belongs to a selected class that still needs test views; ``test_per_class``
  per class (the paper: 1500).
* **View overlap (VO)** of a test view: the intersection over union (in %) of its
  visibility polygon and that of its class's training viewpoint (the real image for
  the real class, the synthesis target for the others). ``vo_landmark`` is the same
  against the cell's one real image. Levels: L1 ``VO > 60``, L2 ``30 < VO <= 60``,
  L3 ``VO <= 30``, from ``vo`` by default (``level_reference = "landmark"`` uses
  ``vo_landmark``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import shapely

from ssga_core.errors import InputError
from ssga_core.geometry import Pose
from ssga_bench.protocol_config import ProtocolConfig
from ssga_bench.protocol_fit import Fit, Suggestion, fit_protocol, suggest, suggestion_kinds
from ssga_bench.protocol_geometry import VIEWPOINT_STEPS
from ssga_bench.protocol_plan import Grid, Plan, Sample, Split, capture_height, level_of
from ssga_bench.protocol_sampling import ProtocolSampling
from ssga_bench.seeds import stream

__all__ = [
    "FULL_REACH",
    "VIEWPOINT_STEPS",
    "Fit",
    "Grid",
    "Plan",
    "Protocol",
    "ProtocolConfig",
    "Sample",
    "Split",
    "Suggestion",
    "capture_height",
    "fit_protocol",
    "level_of",
    "suggest",
    "suggestion_kinds",
]

FULL_REACH = 0.5
"""Cells whose canonical viewpoints all stand at least this share of
``viewpoint_distance`` back are drawn before cells that need nearer ones."""


class Protocol(ProtocolSampling):
    """The protocol for one floor plan and camera (see the module docstring)."""

    # --- the plan -------------------------------------------------------------
    def plan(self, workspace: str, height: float = 1.5, progress: Callable[[int, int], None] | None = None) -> Plan:
        """Draw the cells, the training and target viewpoints and the test views, for a
        workspace that renders any pose.

        Args:
            workspace: name recorded in the plan.
            height: camera height of every viewpoint.
            progress: called with ``(test views found, test views wanted)``.

        Raises:
            InputError: the floor plan has fewer eligible cells than ``cells``, or test
                views cannot be placed.
        """
        c = self.config
        rng = stream(c.seed, "cells")
        chosen = self._choose_cells(self.free_cells(rng), height, workspace)
        reals = [int(rng.integers(c.orientations)) for _ in chosen]
        samples, training, real_place = self._training_samples(chosen, reals, {})
        cells = [cell for cell, _ in chosen]
        samples.extend(self._sample_tests(cells, training, real_place, height, stream(c.seed, "test"), progress))
        if c.val_per_class:
            val_rng = stream(c.seed, "val")
            samples.extend(self._sample_tests(cells, training, real_place, height, val_rng, None, split="val", per_class=c.val_per_class))
        return Plan(workspace, c, self.grid, tuple(cell for cell, _ in chosen), tuple(samples))

    def select(self, workspace: str, captures: Sequence[Pose]) -> Plan:
        """The plan for a captured workspace: training and test views chosen among ``captures``.

        Each capture is assigned to its class; ``cells`` cells that have captures (and
        canonical viewpoints for every heading) are drawn; each gets as its real image a
        random capture of a random class that has one, and up to ``test_per_class`` other
        captures per class as test views. Targets are canonical viewpoints, as for
        rendered workspaces.

        Raises:
            InputError: a capture stands outside the floor plan's free floor, or too few
                cells have captures.
        """
        c = self.config
        rng, test_rng = stream(c.seed, "cells"), stream(c.seed, "test")
        xy = np.array([[p.x, p.y] for p in captures], dtype=np.float64).reshape(-1, 2)
        yaw = np.array([p.yaw for p in captures], dtype=np.float64)
        inside = shapely.contains_xy(self._free_tolerant, xy[:, 0], xy[:, 1])
        if not inside.all():
            k = int(np.flatnonzero(~inside)[0])
            raise InputError(
                f"workspace {workspace!r}: capture {k} at ({xy[k, 0]:.2f}, {xy[k, 1]:.2f}) stands outside the floor plan's free "
                f"floor ({int((~inside).sum())} captures do); check the poses' frame and the floor plan"
            )
        distances = self.rays(xy, yaw)
        cells, orientations = self.assign(xy, yaw, distances), self.orientation_of(yaw)
        by_class: dict[tuple[int, int], list[int]] = {}
        for k, key in enumerate(zip(cells.tolist(), orientations.tolist())):
            if key[0] >= 0:
                by_class.setdefault(key, []).append(k)
        height = capture_height(captures)
        with_captures = sorted({cell for cell, _ in by_class})
        chosen = self._choose_cells([with_captures[i] for i in rng.permutation(len(with_captures))], height, workspace, captures)
        reals, train_index = [], {}
        for rank, (cell, _) in enumerate(chosen):
            real = int(rng.choice([o for o in range(c.orientations) if (cell, o) in by_class]))
            reals.append(real)
            train_index[rank * c.orientations + real] = int(rng.choice(by_class[(cell, real)]))
        samples, training, real_place = self._training_samples(chosen, reals, {p: captures[k] for p, k in train_index.items()}, train_index)
        polygons = {place: self.polygon(pose) for place, pose in training.items()}
        for rank, (cell, _) in enumerate(chosen):
            for o in range(c.orientations):
                place = rank * c.orientations + o
                pool = [k for k in by_class.get((cell, o), []) if k != train_index.get(place)]
                for n, k in enumerate(sorted(test_rng.permutation(pool)[: c.test_per_class].tolist())):
                    samples.append(self._test_sample(place, cell, o, captures[k], distances[k], polygons, real_place, n, source=k))
        return Plan(workspace, c, self.grid, tuple(cell for cell, _ in chosen), tuple(samples))

    def _choose_cells(
        self, candidates: list[int], height: float, workspace: str, captures: Sequence[Pose] | None = None
    ) -> list[tuple[int, list[Pose]]]:
        """The first ``cells`` candidates whose every heading has a canonical viewpoint, those
        whose viewpoints all stand at least :data:`FULL_REACH` back first, in candidate order."""
        c = self.config
        full: list[tuple[int, list[Pose]]] = []
        near: list[tuple[int, list[Pose]]] = []
        for cell in candidates:
            found = self.canonical_viewpoints(cell, height)
            if any(f is None for f in found):
                continue
            reach = min(step for _, step in found)  # type: ignore[misc]
            (full if reach >= FULL_REACH else near).append((cell, [pose for pose, _ in found]))  # type: ignore[misc]
            if len(full) == c.cells:
                return full
        if len(full) + len(near) >= c.cells:
            rank = {cell: i for i, cell in enumerate(candidates)}
            return sorted(full + near[: c.cells - len(full)], key=lambda chosen: rank[chosen[0]])
        found_cells = len(full) + len(near)
        fits = suggest(self.floor_plan, self.camera, c, height=height, captures=captures, limit=c.cells, stop_after=2).fits
        instead = "; ".join(f"{f.describe(c)} gives {'at least ' if not f.complete else ''}{f.cells}" for f in suggestion_kinds(fits, c)[:2])
        raise InputError(
            f"workspace {workspace!r}: only {found_cells} of its {len(self.centroids)} cells of {c.cell_size} m can be "
            f"seen from all {c.orientations} headings, {c.cells} wanted; "
            + (f"{instead}, or " if instead else f"no cell_size or viewpoint_distance tried gives {c.cells}; ")
            + (f"lower protocol.cells to {found_cells}" if found_cells else "lower protocol.cells")
            + " (`ssga workspace build --suggest` shows every value tried)"
        )
