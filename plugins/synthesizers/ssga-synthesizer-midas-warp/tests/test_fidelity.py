"""The v2.1-small backbone side by side with geffnet's ``tf_efficientnet_lite3``, the module MiDaS builds it from.

MiDaS's ``_make_efficientnet_backbone`` takes geffnet's ``tf_efficientnet_lite3``
(``exportable=True``) and regroups its stem and blocks into ``pretrained.layer1..4``.
geffnet 1.0.2 is installed with ``--no-deps`` (``requirements-nodeps.txt``: a plain
install would pull torchvision and a CUDA torch); it imports without torchvision. The
official MiDaS repository is not installable from PyPI, so the whole network was compared
with it once in a session (max abs difference 0.0: the README's "Fidelity"); here the
decoder is checked by its state-dict layout (``test_model.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn
from ssga_synthesizer_midas_warp.model import V21_SMALL, EfficientNetStages

geffnet = pytest.importorskip("geffnet")

TOLERANCE = 1e-5
"""Largest absolute difference allowed between the two backbones' stage outputs (measured: 0.0, the same operations)."""


def official_backbone(seed: int) -> nn.Module:
    """MiDaS's ``_make_efficientnet_backbone(geffnet.create_model("tf_efficientnet_lite3", exportable=True))``, random weights."""
    torch.manual_seed(seed)
    effnet = geffnet.create_model("tf_efficientnet_lite3", pretrained=False, exportable=True)
    pretrained = nn.Module()
    pretrained.layer1 = nn.Sequential(effnet.conv_stem, effnet.bn1, effnet.act1, *effnet.blocks[0:2])
    pretrained.layer2 = nn.Sequential(*effnet.blocks[2:3])
    pretrained.layer3 = nn.Sequential(*effnet.blocks[3:5])
    pretrained.layer4 = nn.Sequential(*effnet.blocks[5:9])
    with torch.no_grad():  # BN statistics and affine parameters that are not the identity
        for m in pretrained.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.running_mean.normal_(0.0, 0.1)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.normal_(1.0, 0.2)
                m.bias.normal_(0.0, 0.2)
    return pretrained.eval()


def test_geffnet_builds_the_reference_without_torchvision():
    import sys

    assert "torchvision" not in sys.modules
    reference = official_backbone(0)
    eps = {m.eps for m in reference.modules() if isinstance(m, nn.BatchNorm2d)}
    assert eps == {1e-3}
    assert {type(m).__name__ for m in reference.modules()} >= {"Conv2dSameExport", "ReLU6"}


@pytest.fixture(scope="module")
def pair() -> tuple[nn.Module, nn.Module]:
    """The reference and ours with the same weights (the reference's state dict loads strictly into ours)."""
    reference = official_backbone(1)
    ours = EfficientNetStages(V21_SMALL).eval()
    state = reference.state_dict()
    assert len(state) == 432 and set(state) == set(ours.state_dict())
    ours.load_state_dict(state, strict=True)
    return reference, ours


@pytest.mark.parametrize("size", [(256, 256), (160, 256), (250, 333)], ids=["256x256", "160x256", "odd-250x333"])
def test_the_backbone_matches_geffnet(pair, size):
    """Same weights, same input: the four stage outputs agree (TF "SAME" padding at even and odd sizes)."""
    reference, ours = pair
    for m in reference.modules():  # geffnet's exportable conv keeps the padding of the first size it saw: forget it
        if type(m).__name__ == "Conv2dSameExport":
            m.pad = None
    x = torch.randn(1, 3, *size, generator=torch.Generator().manual_seed(2))
    with torch.inference_mode():
        expected = []
        h = x
        for layer in (reference.layer1, reference.layer2, reference.layer3, reference.layer4):
            h = layer(h)
            expected.append(h)
        got = ours(x)
    diffs = [float((a - b).abs().max()) for a, b in zip(expected, got, strict=True)]
    scale = [float(a.abs().max()) for a in expected]
    print(f"{size}: max abs difference per stage {diffs} (outputs up to {max(scale):.1f})")
    assert [tuple(g.shape[1:2]) for g in got] == [(32,), (48,), (136,), (384,)]
    assert max(diffs) <= TOLERANCE
    assert np.all(np.array(scale) > 1.0)  # not a comparison of zeros
