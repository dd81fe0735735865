"""Speed of the Patch-NetVLAD descriptor on the CPU (``make bench``): images per second at 256 x 256.

* extraction through the plugin, one view at a time (what ``fit`` and the pipeline do):
  the light network (the packaged default's layout) and the full VGG16 (the official
  models' layout), both on random weights (same cost);
* the bare VGG16 network on a batch of 16, to compare with the roof measured on the
  2-core dev machine for VGG16 to conv5_3 at 256 x 256: ~3.5 images/s (REFERENCE §11).

Each records ``images_per_s`` (from the median) and the torch threads it ran with.
Run alone with ``pytest benchmarks/bench_pnv.py -o python_files=bench_*.py --benchmark-enable``.
"""

from __future__ import annotations

import pytest

pytest.importorskip("ssga_descriptor_pnv")

import torch  # noqa: E402
from ssga_descriptor_pnv.model import VGG16_WIDTHS, PatchNetVLAD  # noqa: E402
from ssga_descriptor_pnv.plugin import Pnv, PnvConfig  # noqa: E402

from ssga_core.testing import make_view  # noqa: E402


def _images_per_s(benchmark, images: int) -> None:
    benchmark.extra_info["threads"] = torch.get_num_threads()
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        benchmark.extra_info["images_per_s"] = round(images / stats.stats.median, 2)


@pytest.mark.parametrize(("network", "rounds"), [("light", 20), ("vgg16", 5)])
def test_pnv_extract_one_256px_view(benchmark, network, rounds):
    """144 x 512 local features of one view: light ~12-14 images/s, VGG16 ~2 images/s measured (1 thread, busy machine)."""
    d = Pnv(PnvConfig(weights="random", network=network, device="cpu"))
    view = make_view(seed=0)
    local = benchmark.pedantic(d.extract, args=(view,), rounds=rounds, warmup_rounds=1)
    assert local.descriptors.shape == (144, 512)
    _images_per_s(benchmark, 1)


def test_vgg16_network_batch_of_16_at_256px(benchmark):
    """The whole network (encoder, pool with patches, WPCA) on 16 images, channels_last as the roof was measured."""
    net = PatchNetVLAD(VGG16_WIDTHS, 16, 512).eval().to(memory_format=torch.channels_last)
    x = torch.randn(16, 3, 256, 256).contiguous(memory_format=torch.channels_last)

    def forward():
        with torch.inference_mode():
            return net(x)

    local, _ = benchmark.pedantic(forward, rounds=3, warmup_rounds=1)
    assert local.shape == (16, 144, 512)
    _images_per_s(benchmark, 16)
