"""Speed of the cascade-seg parser (``make bench``): seconds per 256 x 256 view, CPU, one torch thread.

Each case parses ``make_view``'s painted wall (the network's cost does not depend on
the content; the regions' cost is a few milliseconds). Networks:

* ``light``: the packaged network trained here (procedural vocabulary);
* ``resnet18dilated``, ``resnet50dilated``: the official layouts (ADE20K, 150 classes)
  on **random weights, for timing only**: the released files are not shipped, and a
  network's speed does not depend on its weights.

Scales, as the parser's ``image_sizes``:

* ``single``: one scale; the light network at the view's own 256 px, the official ones
  at 450 (the middle of CSAIL's test scales; a 256-pixel view is upsampled to 456);
* ``multi``: CSAIL's test (probabilities averaged over five scales): 300-600 for the
  official networks, the same ratios around 256 (176-336) for the light one;
* ``native`` (official networks only): one scale at the view's own 256 px.

torch runs on one thread (the benchmark machine has two busy cores). Run alone with
``pytest benchmarks/bench_cascade_seg.py -o python_files=bench_*.py --benchmark-enable``.
"""

from __future__ import annotations

import pytest

pytest.importorskip("ssga_parser_cascade_seg")
torch = pytest.importorskip("torch")

from ssga_parser_cascade_seg.plugin import LIGHT_SCALES, ORIGINAL_SCALES, CascadeSeg, CascadeSegConfig  # noqa: E402

from ssga_core.testing import make_view  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")

NETWORKS = {
    "light": {},
    "resnet18dilated": {"network": "resnet18dilated", "classes": "ade20k", "weights": "random"},
    "resnet50dilated": {"network": "resnet50dilated", "classes": "ade20k", "weights": "random"},
}
SCALES = {
    ("light", "single"): (256,),
    ("light", "multi"): LIGHT_SCALES,
    **{(net, "single"): (450,) for net in ("resnet18dilated", "resnet50dilated")},
    **{(net, "multi"): ORIGINAL_SCALES for net in ("resnet18dilated", "resnet50dilated")},
    **{(net, "native"): (256,) for net in ("resnet18dilated", "resnet50dilated")},
}
ROUNDS = {"light": 20, "resnet18dilated": 5, "resnet50dilated": 3}
"""Rounds per case: the official networks take seconds per view on one thread."""


@pytest.mark.parametrize(("network", "scales"), sorted(SCALES))
def test_parse(benchmark, network, scales):
    parser = CascadeSeg(CascadeSegConfig(device="cpu", image_sizes=SCALES[network, scales], **NETWORKS[network]))
    view = make_view(seed=5)
    parser.parse(view)  # warm-up: first-call allocations
    regions = benchmark.pedantic(parser.parse, args=(view,), rounds=ROUNDS[network], iterations=1)
    assert regions.labels.shape == (256, 256)
    benchmark.extra_info["weights"] = "packaged" if network == "light" else "random (timing only)"
    benchmark.extra_info["image_sizes"] = list(SCALES[network, scales])
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        benchmark.extra_info["s_per_view"] = round(stats.stats.median, 3)
