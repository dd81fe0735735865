"""Where a run's time goes: per stage and phase of the work, per phase of the run, and the
views each per-view stage handled (``timings.json``); :func:`instrument` times a bound
variant's stages."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator, Mapping
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field
from typing import Any

from ssga_core.pipeline import BoundVariant


@dataclass
class Timings:
    """Where the time goes.

    Attributes:
        seconds: per stage and phase of the work (load views, parse, describe,
            synthesize, train, evaluate...), summed over every worker that did it: what
            each costs, whatever the executor.
        wall: per phase of the run as the driver waits for it (workspace, real views,
            variants, report): with several workers, less than the work it holds.
        views: how many views each per-view stage handled (for its rate, views per second).
    """

    seconds: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    wall: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    views: dict[str, int] = field(default_factory=lambda: defaultdict(int))

    def phase(self, name: str) -> AbstractContextManager[None]:
        """Time the block as work of ``name``."""
        return _timed(self.seconds, name)

    def wall_phase(self, name: str) -> AbstractContextManager[None]:
        """Time the block as a phase of the run the driver waits for."""
        return _timed(self.wall, name)

    def add(self, other: Timings | Mapping[str, float]) -> None:
        """Add another's figures (a worker's)."""
        if isinstance(other, Timings):
            for phase, seconds in other.wall.items():
                self.wall[phase] += seconds
            for stage, count in other.views.items():
                self.views[stage] += count
            other = other.seconds
        for phase, seconds in other.items():
            self.seconds[phase] += seconds

    def clear(self) -> None:
        for figures in (self.seconds, self.wall, self.views):
            figures.clear()

    def take(self) -> Timings:
        """A copy of the figures, which are then cleared (a worker's, sent back per task)."""
        out = Timings()
        out.add(self)
        self.clear()
        return out

    def to_json(self) -> dict[str, dict[str, float]]:
        return {"wall": dict(self.wall), "work": dict(self.seconds), "views": dict(self.views)}

    def wrap(self, obj: object, method: str, phase: str, per_view: bool = False) -> None:
        """Time every call of ``obj.method`` under ``phase`` (an instance attribute shadows the
        method); ``per_view``: each call handles one view, counted for the phase's rate."""
        inner = getattr(obj, method)

        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.phase(phase):
                out = inner(*args, **kwargs)
            if per_view:
                self.views[phase] += 1
            return out

        setattr(obj, method, timed)


@contextmanager
def _timed(into: dict[str, float], name: str) -> Iterator[None]:
    start = time.perf_counter()
    try:
        yield
    finally:
        into[name] += time.perf_counter() - start


def instrument(bound: BoundVariant, timings: Timings) -> None:
    if bound.parser is not None:
        timings.wrap(bound.parser, "parse", "parse", per_view=True)
    phases = {"extract": "describe", "describe": "describe", "pool": "pool (node features)", "fit": "fit descriptor"}
    for method, phase in phases.items():
        if hasattr(bound.descriptor, method):
            timings.wrap(bound.descriptor, method, phase, per_view=method in ("extract", "describe"))
    if bound.synthesizer is not None:
        timings.wrap(bound.synthesizer, "synthesize", "synthesize", per_view=True)
