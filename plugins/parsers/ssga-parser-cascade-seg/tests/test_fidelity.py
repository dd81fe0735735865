"""Side by side with CSAIL's own code (``mit_semseg`` 1.0.0, installed with --no-deps):
the official modules' state dicts, saved as the releases are, load strictly here and give
the same probabilities, single- and multi-scale.

``mit_semseg.models`` imports torch only; its ``ModelBuilder`` would download ImageNet
weights, so the test builds the modules as the builder does, from ``resnet`` and
``models``, on random weights (the released files are not downloadable here).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

mit_models = pytest.importorskip("mit_semseg.models.models")
mit_resnet = pytest.importorskip("mit_semseg.models.resnet")

from ssga_parser_cascade_seg.plugin import FILES, CascadeSeg, CascadeSegConfig  # noqa: E402

from ssga_bench import checkpoint_bytes  # noqa: E402
from ssga_core.testing import make_view  # noqa: E402

ARCHITECTURES = {"resnet18dilated": (mit_resnet.resnet18, 512), "resnet50dilated": (mit_resnet.resnet50, 2048)}


def official(network: str, seed: int = 0):
    """CSAIL's encoder and decoder as ModelBuilder builds them (``use_softmax=True``: inference), with random
    weights and batch-norm statistics that differ from the identity."""
    resnet, fc_dim = ARCHITECTURES[network]
    torch.manual_seed(seed)
    encoder = mit_models.ResnetDilated(resnet(pretrained=False), dilate_scale=8)
    decoder = mit_models.PPMDeepsup(num_class=150, fc_dim=fc_dim, use_softmax=True)
    decoder.apply(mit_models.ModelBuilder.weights_init)
    with torch.no_grad():
        for m in [*encoder.modules(), *decoder.modules()]:
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.1, 0.1)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.1, 0.1)
    return encoder.eval(), decoder.eval()


def release(tmp_path, encoder, decoder):
    """The modules saved as CSAIL's train.py saves a checkpoint: raw state dicts, one file per part."""
    folder = tmp_path / "release"
    folder.mkdir()
    for part, module in (("encoder", encoder), ("decoder", decoder)):
        (folder / FILES[part]).write_bytes(checkpoint_bytes(module.state_dict()))
    return folder


def csail_test(encoder, decoder, rgb: np.ndarray, image_sizes, max_size: int = 1000, padding: int = 8) -> np.ndarray:
    """CSAIL's test.py for one image: TestDataset's resizing (PIL bilinear) and normalisation, then
    SegmentationModule's inference, the probabilities averaged over the scales."""
    from PIL import Image

    h, w = rgb.shape[:2]
    scores = torch.zeros(1, 150, h, w)
    for short in image_sizes:
        scale = min(short / float(min(h, w)), max_size / float(max(h, w)))
        th, tw = int(h * scale), int(w * scale)
        tw, th = ((tw - 1) // padding + 1) * padding, ((th - 1) // padding + 1) * padding
        img = np.float32(np.array(Image.fromarray(rgb).resize((tw, th), Image.BILINEAR))) / 255.0
        x = (torch.from_numpy(img.transpose(2, 0, 1)) - torch.tensor([0.485, 0.456, 0.406])[:, None, None]) / torch.tensor([0.229, 0.224, 0.225])[:, None, None]
        with torch.no_grad():
            scores += decoder(encoder(x[None], return_feature_maps=True), segSize=(h, w)) / len(image_sizes)
    return scores[0].numpy()


@pytest.mark.parametrize("network", ["resnet18dilated", "resnet50dilated"])
def test_official_modules_load_strictly_and_agree(tmp_path, network):
    torch.set_num_threads(1)
    encoder, decoder = official(network)
    # REFERENCE §5's counts, from CSAIL's modules (synchronized batch norm buffers included).
    counts = {"resnet18dilated": 207, "resnet50dilated": 495}
    assert (len(encoder.state_dict()), len(decoder.state_dict())) == (counts[network], 58)
    # The files alone: their keys and shapes say the network and the vocabulary.
    parser = CascadeSeg(CascadeSegConfig(weights=str(release(tmp_path, encoder, decoder)), device="cpu", image_sizes=(64,)))
    assert (parser.config.network, parser.config.classes) == (network, "ade20k")
    rgb = make_view(seed=6, size=64).rgb
    # One scale at the image's own size: no resizing, so the networks alone are compared (measured: identical).
    np.testing.assert_allclose(parser.probabilities(rgb), csail_test(encoder, decoder, rgb, (64,)), atol=1e-6)


def test_multi_scale_inference_agrees_with_csails_test(tmp_path):
    torch.set_num_threads(1)
    encoder, decoder = official("resnet18dilated", seed=1)
    rgb = make_view(seed=7, size=96).rgb[:, :80]  # 96 x 80: every scale resizes, and rounds up to multiples of 8
    sizes = (48, 60, 72)
    folder = release(tmp_path, encoder, decoder)
    parser = CascadeSeg(CascadeSegConfig(weights=str(folder), network="resnet18dilated", classes="ade20k", device="cpu", image_sizes=sizes))
    ours, theirs = parser.probabilities(rgb), csail_test(encoder, decoder, rgb, sizes)
    # PIL resizes 8-bit images (rounding each pixel) where torch resizes floats: the probabilities differ
    # by that rounding's effect only (measured: 1.0e-4 at most); random weights give nearly flat
    # probabilities, so the classes of a few near-ties differ (measured: 0.1 % of the pixels).
    assert np.abs(ours - theirs).max() < 1e-3
    assert (ours.argmax(0) == theirs.argmax(0)).mean() > 0.99
