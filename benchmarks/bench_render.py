"""Speed of the mesh workspace's ray-casting renderer (``make bench``).

A 50k-triangle scene with a texture per object (``textured_clutter``: a room full of
subdivided textured boxes), 256 x 256 views from random poses inside it, hfov 90.
Run alone with ``pytest benchmarks/bench_render.py -o python_files='bench_*.py' --benchmark-enable``.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ssga_workspace_mesh")

from ssga_core import Camera, Pose  # noqa: E402
from ssga_workspace_mesh.renderer import MeshRenderer  # noqa: E402
from ssga_workspace_mesh.scenes import textured_clutter  # noqa: E402

BATCH = 120  # render_many starts worker processes from 50 poses per worker


@pytest.fixture(scope="module")
def renderer() -> MeshRenderer:
    return MeshRenderer(textured_clutter(triangles=50_000), Camera(width=256, height=256, hfov_deg=90.0))


@pytest.fixture(scope="module")
def poses() -> list[Pose]:
    rng = np.random.default_rng(0)
    xy, yaw = rng.uniform(-4.5, 4.5, (BATCH, 2)), rng.uniform(-np.pi, np.pi, BATCH)
    return [Pose(float(x), float(y), float(a), 1.5) for (x, y), a in zip(xy, yaw, strict=True)]


def test_render_one_view(benchmark, record_rate, renderer, poses):
    """One process, one thread: ~20 ms per view measured on the 2-core dev machine."""
    benchmark.extra_info["triangles"] = renderer.num_triangles
    it = iter(poses * 1000)
    view = benchmark(lambda: renderer.render(next(it)))
    assert view.valid_depth().all()
    record_rate(1)


@pytest.mark.parametrize("workers", [1, 2])
def test_render_many(benchmark, record_rate, renderer, poses, workers):
    """A batch of views in this process, or in two worker processes (their start-up included)."""
    benchmark.extra_info["triangles"] = renderer.num_triangles
    views = benchmark.pedantic(renderer.render_many, args=(poses,), kwargs={"workers": workers}, rounds=3)
    assert len(views) == BATCH
    record_rate(BATCH)
