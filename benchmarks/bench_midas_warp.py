"""Speed of the midas-warp synthesizer (``make bench``): MiDaS depth from RGB, then depth-warp.

One 256 x 256 RGB-only view (no depth) rendered at the next of 32 nearby poses (up to
0.5 m away, turned up to 30 degrees) per call, as in ``bench_synthesis.py``. Three costs:

* ``new view``: every call brings a view the synthesizer has not seen (a new ``View``
  object), so MiDaS runs and then the warp: the cost of a view rendered at one target;
* ``same view``: one view at many targets, as the pipeline renders each real view at
  its cell's other viewpoints: MiDaS runs once, then the warp alone (its depth is cached
  per view);
* ``depth``: the network and calibration alone (``estimate_depth``).

``light`` is the packaged network; ``v21-small`` is MiDaS v2.1 small's architecture on
random weights (the official file is not shipped; its speed does not depend on its
weights). torch runs on one thread (the benchmark machine has two busy cores). Run alone with
``pytest benchmarks/bench_midas_warp.py -o python_files=bench_*.py --benchmark-enable``.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ssga_synthesizer_midas_warp")
torch = pytest.importorskip("torch")

from ssga_core import Pose, View  # noqa: E402
from ssga_core.testing import make_view  # noqa: E402
from ssga_synthesizer_midas_warp.plugin import MidasWarp, MidasWarpConfig  # noqa: E402

POSES = 32
NETWORKS = {
    "light": {},
    "v21-small": {"network": "v21-small", "weights": "random", "calibration": "minmax"},
}


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def view() -> View:
    v = make_view(seed=5)
    return View(rgb=v.rgb, pose=v.pose, camera=v.camera)  # RGB only


@pytest.fixture(scope="module")
def targets() -> list[Pose]:
    rng = np.random.default_rng(1)
    offsets = rng.uniform(-0.5, 0.5, (POSES, 2))
    yaws = rng.uniform(-np.pi / 6, np.pi / 6, POSES)
    return [Pose(float(dx), float(dy), float(yaw)) for (dx, dy), yaw in zip(offsets, yaws, strict=True)]


def _per_view(benchmark) -> None:
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        benchmark.extra_info["ms_per_view"] = round(1000 * stats.stats.median, 2)
        benchmark.extra_info["views_per_s"] = round(1 / stats.stats.median, 1)


@pytest.mark.parametrize("network", list(NETWORKS))
def test_synthesize_new_view(benchmark, view, targets, network):
    synthesizer = MidasWarp(MidasWarpConfig(device="cpu", **NETWORKS[network]))
    it = iter(targets * 10_000)
    # A fresh View object each call (same pixels): the depth cache never hits.
    syn = benchmark(lambda: synthesizer.synthesize(View(rgb=view.rgb, pose=view.pose, camera=view.camera), next(it)))
    assert syn.view.depth is not None and syn.view.rgb.shape == (256, 256, 3)
    _per_view(benchmark)


def test_synthesize_same_view(benchmark, view, targets):
    synthesizer = MidasWarp(MidasWarpConfig(device="cpu"))
    it = iter(targets * 10_000)
    syn = benchmark(lambda: synthesizer.synthesize(view, next(it)))
    assert syn.view.depth is not None
    _per_view(benchmark)


@pytest.mark.parametrize("network", list(NETWORKS))
def test_estimate_depth(benchmark, view, network):
    synthesizer = MidasWarp(MidasWarpConfig(device="cpu", **NETWORKS[network]))
    depth = benchmark(lambda: synthesizer.estimate_depth([view.rgb]))
    assert depth.shape == (1, 256, 256)
    _per_view(benchmark)
