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

import pytest

pytest.importorskip("ssga_synthesizer_midas_warp")
torch = pytest.importorskip("torch")

from ssga_core import View  # noqa: E402
from ssga_core.testing import make_view  # noqa: E402
from ssga_synthesizer_midas_warp.plugin import MidasWarp, MidasWarpConfig  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")

NETWORKS = {
    "light": {},
    "v21-small": {"network": "v21-small", "weights": "random", "calibration": "minmax"},
}


@pytest.fixture(scope="module")
def view() -> View:
    v = make_view(seed=5)
    return View(rgb=v.rgb, pose=v.pose, camera=v.camera)  # RGB only


@pytest.mark.parametrize("network", list(NETWORKS))
def test_synthesize_new_view(benchmark, record_rate, view, targets, network):
    synthesizer = MidasWarp(MidasWarpConfig(device="cpu", **NETWORKS[network]))
    it = iter(targets * 10_000)
    # A fresh View object each call (same pixels): the depth cache never hits.
    syn = benchmark(lambda: synthesizer.synthesize(View(rgb=view.rgb, pose=view.pose, camera=view.camera), next(it)))
    assert syn.view.depth is not None and syn.view.rgb.shape == (256, 256, 3)
    record_rate()


def test_synthesize_same_view(benchmark, record_rate, view, targets):
    synthesizer = MidasWarp(MidasWarpConfig(device="cpu"))
    it = iter(targets * 10_000)
    syn = benchmark(lambda: synthesizer.synthesize(view, next(it)))
    assert syn.view.depth is not None
    record_rate()


@pytest.mark.parametrize("network", list(NETWORKS))
def test_estimate_depth(benchmark, record_rate, view, network):
    synthesizer = MidasWarp(MidasWarpConfig(device="cpu", **NETWORKS[network]))
    depth = benchmark(lambda: synthesizer.estimate_depth([view.rgb]))
    assert depth.shape == (1, 256, 256)
    record_rate()
