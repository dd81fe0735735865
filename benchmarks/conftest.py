"""What the speed benchmarks share: target poses to synthesize at, one torch thread, and rates per view."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

from ssga_core import Pose

TARGETS = 32


@pytest.fixture(scope="module")
def targets() -> list[Pose]:
    """Camera moves a synthesizer meets in the pipeline: within 0.5 m sideways and forwards, and 30 degrees of turn."""
    rng = np.random.default_rng(1)
    offsets = rng.uniform(-0.5, 0.5, (TARGETS, 2))
    yaws = rng.uniform(-np.pi / 6, np.pi / 6, TARGETS)
    return [Pose(float(dx), float(dy), float(yaw)) for (dx, dy), yaw in zip(offsets, yaws, strict=True)]


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """One torch thread unless a test sets more: on the shared 2-core machine two threads wait on each other."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def record_rate(benchmark) -> Callable[..., None]:
    """``record_rate(views=1)``: the median's views per second and milliseconds per view, in the benchmark's extra info."""

    def record(views: int = 1) -> None:
        stats = getattr(benchmark, "stats", None)
        if stats is not None and getattr(stats, "stats", None) is not None:  # None with --benchmark-disable
            benchmark.extra_info["views_per_s"] = round(views / stats.stats.median, 2)
            benchmark.extra_info["ms_per_view"] = round(1000 * stats.stats.median / views, 2)

    return record
