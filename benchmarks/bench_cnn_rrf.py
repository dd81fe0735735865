"""Speed of the CNN-RRF descriptor's networks (``make bench``): images per second.

* inference: a batch of crops through the whole classifier (eval mode, channels-last),
  the light network at its 112 px input and VGG16 at 256 x 256, the size
  REFERENCE §11 measured VGG16's conv5_3 backbone at (≈ 3.5 images/s on the 2-core dev
  machine: the roof for VGG16 here; the fully connected layers add < 1 % to its FLOPs);
* describe: one 256 x 256 view with 64 regions (about what SLICO's default gives), i.e.
  65 crops of the light network;
* training: one AdamW step of augmented samples, the light network at its defaults (32
  samples of 112 px) and VGG16 on 8 samples of 128 px (REFERENCE: ≈ 3 images/s).

Each test records ``images_per_s`` in ``extra_info``. Run alone with
``pytest benchmarks/bench_cnn_rrf.py -o python_files='bench_*.py' --benchmark-enable``.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ssga_descriptor_cnn_rrf")

import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from ssga_descriptor_cnn_rrf.plugin import CnnRrf, CnnRrfConfig  # noqa: E402
from ssga_descriptor_cnn_rrf.training import Augmentation  # noqa: E402
from ssga_descriptor_cnn_rrf.vgg import VGG  # noqa: E402

from ssga_core import Regions  # noqa: E402
from ssga_core.testing import make_view  # noqa: E402

CLASSES = 48  # the demo's place classes

LIGHT = CnnRrfConfig()
NETWORKS = {
    "light": (
        lambda: VGG(LIGHT.arch, CLASSES, width=LIGHT.width, hidden=LIGHT.hidden, pool=LIGHT.pool, batch_norm=LIGHT.batch_norm),
        LIGHT.input_size,
    ),
    "vgg16": (lambda: VGG("vgg16", CLASSES), 256),
}


def _images_per_s(benchmark, images: int) -> None:
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        benchmark.extra_info["images_per_s"] = round(images / stats.stats.median, 2)


@pytest.mark.parametrize("network, batch", [("light", 64), ("vgg16", 16)])
def test_inference(benchmark, network, batch):
    make, size = NETWORKS[network]
    net = make().eval().to(memory_format=torch.channels_last)
    x = torch.rand(batch, 3, size, size).contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        out = benchmark.pedantic(net, args=(x,), rounds=3 if network == "vgg16" else 5, warmup_rounds=1)
    assert out.shape == (batch, CLASSES)
    _images_per_s(benchmark, batch)


def test_describe_a_view_with_64_regions(benchmark):
    d = CnnRrf(CnnRrfConfig(weights="random"))
    view = make_view(seed=0)
    d.fit([view, make_view(seed=1)], [0, 1])
    # 64 regions: an 8 x 8 grid of 32 px cells.
    v, u = np.mgrid[0:256, 0:256]
    regions = Regions.from_labels((v // 32 * 8 + u // 32).astype(np.int32))
    features = benchmark.pedantic(d.describe, args=(view, regions), rounds=5, warmup_rounds=1)
    assert features.shape == (65, 2)
    _images_per_s(benchmark, 65)


@pytest.mark.parametrize("network, batch, size", [("light", 32, LIGHT.input_size), ("vgg16", 8, 128)])
def test_training_step(benchmark, network, batch, size):
    make, _ = NETWORKS[network]
    net = make().train().to(memory_format=torch.channels_last)
    optimiser = torch.optim.AdamW(net.parameters(), lr=1e-4)
    images = [torch.from_numpy(make_view(seed=s).rgb).permute(2, 0, 1).contiguous() for s in range(8)]
    augmentation = Augmentation(size=size)
    rng = np.random.default_rng(0)
    targets = torch.arange(batch) % CLASSES

    def step() -> float:
        x = augmentation.batch(images, rng.integers(0, len(images), batch), rng)
        loss = F.cross_entropy(net(x), targets)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        return float(loss.detach())

    loss = benchmark.pedantic(step, rounds=3, warmup_rounds=1)
    assert np.isfinite(loss)
    _images_per_s(benchmark, batch)
