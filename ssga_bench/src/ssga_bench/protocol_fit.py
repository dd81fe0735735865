"""Which protocol values fit a floor plan: the ``cell_size`` and ``viewpoint_distance`` that
give enough eligible cells, and a ``test_radius`` that places every test view
(:func:`suggest`, ``ssga workspace build --suggest``; :func:`fit_protocol`, ``protocol.fit``)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ssga_core.errors import InputError
from ssga_core.geometry import Camera, Pose
from ssga_bench.protocol_config import ProtocolConfig
from ssga_bench.workspace import FloorPlan

CELL_SIZES = (0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
VIEWPOINT_DISTANCES = (0.25, 0.5, 0.75, 1.0, 1.5, 2.0)
TEST_RADII = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
"""Values :func:`suggest` tries besides the configured ones (metres)."""


@dataclass(frozen=True)
class Fit:
    """How many eligible cells (seen from all headings) one ``cell_size`` and
    ``viewpoint_distance`` give on a floor plan."""

    cell_size: float
    viewpoint_distance: float
    cells: int
    """Eligible cells found."""
    grid_cells: int
    """Cells of the grid at this size."""
    wanted: int
    complete: bool
    """False when counting stopped once ``wanted`` were found: there may be more."""

    @property
    def enough(self) -> bool:
        return self.cells >= self.wanted

    def changes(self, config: ProtocolConfig) -> dict[str, float]:
        """The values that differ from ``config``'s."""
        mine = {"cell_size": self.cell_size, "viewpoint_distance": self.viewpoint_distance}
        return {key: value for key, value in mine.items() if value != getattr(config, key)}

    def describe(self, config: ProtocolConfig) -> str:
        """``protocol.cell_size = 0.75 with protocol.viewpoint_distance = 0.5``, or ``as configured``."""
        return " with ".join(f"protocol.{key} = {value:g}" for key, value in self.changes(config).items()) or "as configured"


@dataclass(frozen=True)
class Suggestion:
    """Protocol values that fit a floor plan (:func:`suggest`)."""

    config: ProtocolConfig
    fits: tuple[Fit, ...]
    """The configured values first, then the others in the order they are suggested."""
    test_radius: float | None = None
    """The test radius with which every class of the first fit with enough cells gets its
    test views, the configured one if it does; None if none tried does or it was not checked."""
    test_radius_checked: bool = False

    @property
    def best(self) -> Fit | None:
        """The first fit with enough cells: the configured values if they have."""
        return next((f for f in self.fits if f.enough), None)


def _alternatives(config: ProtocolConfig) -> list[tuple[float, float]]:
    """``(cell_size, viewpoint_distance)`` pairs, the configured first, then one value changed
    (a nearer viewpoint first: it keeps the cells the user asked for), then both."""
    smaller = sorted((v for v in CELL_SIZES if v < config.cell_size), reverse=True)
    sizes = smaller + sorted(v for v in CELL_SIZES if v > config.cell_size)
    distances = sorted((d for d in VIEWPOINT_DISTANCES if d < config.viewpoint_distance), reverse=True)
    return (
        [(config.cell_size, config.viewpoint_distance)]
        + [(config.cell_size, d) for d in distances]
        + [(size, config.viewpoint_distance) for size in sizes]
        + [(size, d) for size in sizes for d in distances]
    )


def suggestion_kinds(fits: Sequence[Fit], config: ProtocolConfig) -> list[Fit]:
    """The first fit with enough cells of each kind of change from ``config`` (the values it
    changes); changing both values only if changing one does not do."""
    firsts: dict[frozenset[str], Fit] = {}
    for fit in fits:
        if fit.enough and fit.changes(config):
            firsts.setdefault(frozenset(fit.changes(config)), fit)
    single = [fit for kind, fit in firsts.items() if len(kind) == 1]
    return single or list(firsts.values())


def fit_protocol(
    floor_plan: FloorPlan, camera: Camera, config: ProtocolConfig, *, height: float, captures: Sequence[Pose] | None = None
) -> tuple[ProtocolConfig, dict[str, float]]:
    """``config`` with the cell size, viewpoint distance and test radius that fit this floor plan,
    and the values changed: the nearest change that gives ``config.cells`` cells seen from every
    heading (:func:`suggest`), and, for a rendered workspace, a test radius that places every
    test view (checked by planning it).

    Raises:
        InputError: no value tried fits, naming every setting that would, at once.
    """
    suggestion = suggest(floor_plan, camera, config, height=height, captures=captures, limit=config.cells, stop_after=1, check_test_radius=captures is None)
    best = suggestion.best
    if best is None:
        most = max(suggestion.fits, key=lambda f: f.cells)
        raise InputError(
            f"protocol: no cell_size ({', '.join(f'{v:g}' for v in CELL_SIZES)} m) with any viewpoint_distance "
            f"({', '.join(f'{v:g}' for v in VIEWPOINT_DISTANCES)} m) gives {config.cells} cells seen from all {config.orientations} "
            f"headings here; at most {most.cells} ({most.describe(config)}): lower protocol.cells to {most.cells}"
            + (f" with {most.describe(config)}" if most.changes(config) else "")
        )
    changes: dict[str, float] = dict(best.changes(config))
    if captures is None:
        if suggestion.test_radius is None:
            raise InputError(
                f"protocol: with {best.describe(config) if best.changes(config) else 'the configured cells'}, the test views cannot all be placed at any test_radius tried "
                f"({', '.join(f'{r:g}' for r in (config.test_radius, *TEST_RADII))} m); lower protocol.test_per_class "
                f"(now {config.test_per_class}) and protocol.val_per_class, or raise protocol.max_candidates (now {config.max_candidates})"
            )
        if suggestion.test_radius != config.test_radius:
            changes["test_radius"] = suggestion.test_radius
    return config.model_copy(update=changes), changes


def suggest(
    floor_plan: FloorPlan,
    camera: Camera,
    config: ProtocolConfig,
    *,
    height: float = 1.5,
    captures: Sequence[Pose] | None = None,
    limit: int | None = None,
    stop_after: int | None = None,
    check_test_radius: bool = False,
) -> Suggestion:
    """Which ``cell_size`` and ``viewpoint_distance`` give ``config.cells`` eligible cells here.

    Args:
        captures: for a captured workspace, the capture poses: only cells with captures count.
        limit: stop counting a pair's cells once this many are found (the answer is then
            "at least"); None counts them all.
        stop_after: stop trying pairs once this many kinds of change (a nearer viewpoint, another
            cell size, both) have one with enough cells (:func:`suggestion_kinds`).
        check_test_radius: also draw the test views of the first pair with enough cells,
            with the configured ``test_radius`` and, if they cannot all be placed, others
            (:data:`TEST_RADII`, nearest first); rendered workspaces only.
    """
    # Imported here, not at the top: the protocol's cell choice names what would fit in its
    # error (Protocol._choose_cells calls suggest), so ssga_bench.protocol imports this module.
    from ssga_bench.protocol import Protocol

    fits: list[Fit] = []
    for cell_size, distance in _alternatives(config):
        trial = Protocol(floor_plan, camera, config.model_copy(update={"cell_size": cell_size, "viewpoint_distance": distance}))
        if captures is None:
            candidates = trial.free_cells()
        else:
            xy = np.array([[p.x, p.y] for p in captures], dtype=np.float64).reshape(-1, 2)
            assigned = trial.assign(xy, np.array([p.yaw for p in captures], dtype=np.float64))
            candidates = sorted({int(k) for k in assigned if k >= 0})
        found = trial.eligible_cells(candidates, height, limit)
        complete = limit is None or len(found) < limit
        fits.append(Fit(cell_size, distance, len(found), len(trial.centroids), config.cells, complete))
        if stop_after is not None and len(suggestion_kinds(fits[1:], config)) >= stop_after:
            break
    suggestion = Suggestion(config, tuple(fits))
    best = suggestion.best
    if not check_test_radius or captures is not None or best is None:
        return suggestion
    fitting = config.model_copy(update={"cell_size": best.cell_size, "viewpoint_distance": best.viewpoint_distance})
    others = sorted((r for r in TEST_RADII if r != config.test_radius), key=lambda r: (abs(math.log(r / config.test_radius)), r))
    for radius in (config.test_radius, *others):
        try:
            Protocol(floor_plan, camera, fitting.model_copy(update={"test_radius": radius})).plan("suggest", height)
        except InputError:
            continue
        return dataclasses.replace(suggestion, test_radius=radius, test_radius_checked=True)
    return dataclasses.replace(suggestion, test_radius_checked=True)
