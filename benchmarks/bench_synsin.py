"""Speed of the synsin synthesizer on the CPU (``make bench``): synthesized 256 x 256 views per second.

* the light network with its packaged weights, one view per call (what the pipeline
  does), each call at the next of 32 nearby poses (up to 0.5 m away, turned up to 30
  degrees, as ``bench_synthesis.py`` moves depth-warp);
* the same from four views at once (one z-buffer, one refinement);
* the official SynSin layout (MP3D recipe, ``preset = "mp3d"``) on random weights (the
  same cost as the real file), radius 4 and K = 128;
* the splatter alone at the light and the official settings.

Each records ``views_per_s`` (from the median) and the torch threads it ran with.
Run alone with ``pytest benchmarks/bench_synsin.py -o python_files=bench_*.py --benchmark-enable``.
"""

from __future__ import annotations

import pytest

pytest.importorskip("ssga_synthesizer_synsin")

import torch
from ssga_core.testing import make_view
from ssga_synthesizer_synsin.plugin import SynSinConfig, SynSinSynthesizer
from ssga_synthesizer_synsin.splat import splat

from ssga_core import Pose

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.parametrize("threads", [1, 2])
def test_synsin_light_one_view(benchmark, record_rate, targets, threads):
    """Measured 3.4 views/s with one thread, 0.8 with two (the 2-core machine running two other jobs)."""
    torch.set_num_threads(threads)
    benchmark.extra_info["threads"] = threads
    synthesizer = SynSinSynthesizer(SynSinConfig(device="cpu"))
    view = make_view(seed=0)
    it = iter(targets * 10_000)
    syn = benchmark.pedantic(lambda: synthesizer.synthesize(view, next(it)), rounds=20, warmup_rounds=2)
    assert syn.view.rgb.shape == (256, 256, 3)
    record_rate()


def test_synsin_light_from_four_views(benchmark, record_rate, targets):
    """One target from four views 1 m apart, jointly."""
    synthesizer = SynSinSynthesizer(SynSinConfig(device="cpu"))
    views = [
        make_view(seed=s, pose=Pose(float(dx), float(dy), 0.0)) for s, (dx, dy) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1)))
    ]
    it = iter(targets * 10_000)
    out = benchmark.pedantic(lambda: synthesizer.synthesize_from(views, next(it)), rounds=5, warmup_rounds=1)
    assert len(out) == 4
    record_rate()


def test_synsin_official_layout_one_view(benchmark, record_rate, targets):
    """The MP3D model's layout: ResNet blocks of width 64-256 at full resolution; about 0.1-0.2 views/s here."""
    synthesizer = SynSinSynthesizer(SynSinConfig(weights="random", network="synsin", device="cpu"))
    view = make_view(seed=0)
    it = iter(targets * 10_000)
    syn = benchmark.pedantic(lambda: synthesizer.synthesize(view, next(it)), rounds=2, warmup_rounds=0)
    assert syn.view.rgb.shape == (256, 256, 3)
    record_rate()


@pytest.mark.parametrize(("radius", "k", "channels"), [(1.5, 8, 16), (4.0, 128, 64)], ids=["light", "official"])
def test_splat_256px(benchmark, record_rate, radius, k, channels):
    """The splatter alone: 65,536 points with features into one 256 x 256 image."""
    g = torch.Generator().manual_seed(0)
    v, u = torch.meshgrid(torch.arange(256.0), torch.arange(256.0), indexing="ij")
    uv = torch.stack([u.reshape(-1), v.reshape(-1)], -1)[None] * 0.97 + torch.rand(1, 65536, 2, generator=g) * 6  # a slight zoom
    z = 2.0 + torch.rand(1, 65536, generator=g)
    feats = torch.rand(1, 65536, channels, generator=g)

    def run():
        with torch.inference_mode():
            return splat(uv, z, feats, (256, 256), radius=radius, points_per_pixel=k)

    s = benchmark.pedantic(run, rounds=5 if k < 100 else 2, warmup_rounds=1)
    assert s.features.shape == (1, channels, 256, 256)
    record_rate()
