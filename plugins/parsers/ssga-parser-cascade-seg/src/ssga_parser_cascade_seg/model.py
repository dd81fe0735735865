"""The CSAIL ADE20K scene-parsing network in plain torch: a dilated deep-stem ResNet and the PPM decoder.

Module names follow ``mit_semseg`` (CSAILVision/semantic-segmentation-pytorch) so its
released encoder and decoder state dicts load strictly:

* **Encoder** (``ResnetDilated``): a deep stem of three 3 x 3 convolutions (3 -> 64,
  stride 2; 64 -> 64; 64 -> 128; ``conv1/bn1 .. conv3/bn3``), a 3 x 3 max pool, then
  ``layer1..layer4`` of basic (ResNet18) or bottleneck (ResNet50) blocks starting from
  128 channels. ``layer3`` and ``layer4`` keep their resolution and dilate instead (2 and
  4; the block that used to stride dilates by half), so the output stride is 8. No
  ``avgpool``/``fc``.
* **Decoder** (``PPMDeepsup``): pyramid pooling of ``layer4``'s map at 1, 2, 3 and 6 bins
  (``ppm.{i}``: pool, 1 x 1 conv to 512, BN, ReLU), upsampled and concatenated with it;
  ``conv_last``: 3 x 3 conv to 512, BN, ReLU, dropout, 1 x 1 conv to the classes. The
  deep-supervision head on ``layer3`` (``cbr_deepsup``, ``conv_last_deepsup``) trains
  only; inference loads it and never runs it.

Widths are parameters (:class:`Network`): the official ResNet50- and ResNet18-dilated
layouts, and a narrow one trained here (:data:`LIGHT`) with the same keys.
Preprocessing and multi-scale inference are those of CSAIL's ``test.py``
(:func:`scale_sizes`, :func:`predict`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)
"""ImageNet's mean and std, applied to RGB / 255 (``mit_semseg/dataset.py``)."""

POOL_SCALES = (1, 2, 3, 6)

SYNC_BN_BUFFERS = ("_tmp_running_mean", "_tmp_running_var", "_running_iter")
"""The bookkeeping buffers CSAIL's ``SynchronizedBatchNorm2d`` adds to every batch norm;
inference needs none of them (``running_mean``/``running_var`` hold the statistics)."""


@dataclass(frozen=True)
class Network:
    """A layout: block type and counts, stem and stage widths, PPM width."""

    block: Literal["basic", "bottleneck"]
    layers: tuple[int, int, int, int]
    stem: tuple[int, int, int] = (64, 64, 128)
    widths: tuple[int, int, int, int] = (64, 128, 256, 512)
    ppm_dim: int = 512

    @property
    def expansion(self) -> int:
        return 4 if self.block == "bottleneck" else 1

    @property
    def fc_dim(self) -> int:
        """Channels of ``layer4``'s output, the decoder's input (CSAIL's ``fc_dim``)."""
        return self.widths[3] * self.expansion


RESNET50DILATED = Network("bottleneck", (3, 4, 6, 3))
"""``ade20k-resnet50dilated-ppm_deepsup`` (fc_dim 2048)."""
RESNET18DILATED = Network("basic", (2, 2, 2, 2))
"""``ade20k-resnet18dilated-ppm_deepsup`` (fc_dim 512)."""
LIGHT = Network("basic", (2, 2, 2, 2), stem=(16, 16, 32), widths=(16, 32, 64, 128), ppm_dim=64)
"""ResNet18-dilated at a quarter of its widths, PPM at an eighth: the network trained here."""

NETWORKS = {"light": LIGHT, "resnet18dilated": RESNET18DILATED, "resnet50dilated": RESNET50DILATED}


def _conv3x3(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, stride=stride, padding=dilation, dilation=dilation, bias=False)


class BasicBlock(nn.Module):
    def __init__(self, cin: int, planes: int, stride: int, dilations: tuple[int, int], downsample: nn.Module | None) -> None:
        super().__init__()
        self.conv1 = _conv3x3(cin, planes, stride, dilations[0])
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = _conv3x3(planes, planes, 1, dilations[1])
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + (x if self.downsample is None else self.downsample(x)))


class Bottleneck(nn.Module):
    def __init__(self, cin: int, planes: int, stride: int, dilations: tuple[int, int], downsample: nn.Module | None) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = _conv3x3(planes, planes, stride, dilations[0])
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, planes * 4, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(planes * 4)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        return self.relu(out + (x if self.downsample is None else self.downsample(x)))


class ResnetDilated(nn.Module):
    """The encoder: four feature maps (``layer1..layer4``), output stride 8."""

    def __init__(self, net: Network) -> None:
        super().__init__()
        s1, s2, s3 = net.stem
        self.conv1, self.bn1, self.relu1 = _conv3x3(3, s1, 2), nn.BatchNorm2d(s1), nn.ReLU(inplace=True)
        self.conv2, self.bn2, self.relu2 = _conv3x3(s1, s2), nn.BatchNorm2d(s2), nn.ReLU(inplace=True)
        self.conv3, self.bn3, self.relu3 = _conv3x3(s2, s3), nn.BatchNorm2d(s3), nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, stride=2, padding=1)
        block = Bottleneck if net.block == "bottleneck" else BasicBlock
        cin = s3
        # (stride of the plain ResNet, dilation) per stage: CSAIL's _nostride_dilate turns layer3's
        # and layer4's stride 2 into dilation 2 and 4, and the convolution that strode into half that.
        stages = ((1, 1), (2, 1), (2, 2), (2, 4))
        for i, (planes, count, (stride, dilation)) in enumerate(zip(net.widths, net.layers, stages, strict=True)):
            out = planes * net.expansion
            blocks = []
            for j in range(count):
                downsample = None
                if j == 0 and (stride != 1 or cin != out):
                    downsample = nn.Sequential(nn.Conv2d(cin, out, 1, stride=stride if dilation == 1 else 1, bias=False), nn.BatchNorm2d(out))
                if j == 0 and dilation > 1:
                    step, dilations = 1, (dilation // 2, dilation)
                else:
                    step, dilations = (stride if j == 0 else 1), (dilation, dilation)
                # (the strided convolution's dilation, the others'): a basic block's conv1 and conv2, a bottleneck's conv2.
                blocks.append(block(cin, planes, step, dilations, downsample))
                cin = out
            setattr(self, f"layer{i + 1}", nn.Sequential(*blocks))

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = self.relu1(self.bn1(self.conv1(x)))
        x = self.relu2(self.bn2(self.conv2(x)))
        x = self.relu3(self.bn3(self.conv3(x)))
        x = self.maxpool(x)
        out = []
        for layer in (self.layer1, self.layer2, self.layer3, self.layer4):
            x = layer(x)
            out.append(x)
        return out


def _conv_bn_relu(cin: int, cout: int, kernel: int) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, kernel, padding=kernel // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)]


class PPMDeepsup(nn.Module):
    """The decoder: class logits at the encoder's resolution (and the deep-supervision logits in training)."""

    def __init__(self, net: Network, num_class: int) -> None:
        super().__init__()
        fc, d = net.fc_dim, net.ppm_dim
        self.ppm = nn.ModuleList(nn.Sequential(nn.AdaptiveAvgPool2d(s), *_conv_bn_relu(fc, d, 1)) for s in POOL_SCALES)
        self.cbr_deepsup = nn.Sequential(*_conv_bn_relu(fc // 2, fc // 4, 3))
        self.conv_last = nn.Sequential(*_conv_bn_relu(fc + len(POOL_SCALES) * d, d, 3), nn.Dropout2d(0.1), nn.Conv2d(d, num_class, 1))
        self.conv_last_deepsup = nn.Conv2d(fc // 4, num_class, 1)
        self.dropout_deepsup = nn.Dropout2d(0.1)

    def forward(self, features: Sequence[torch.Tensor], deep_supervision: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        conv5 = features[-1]
        size = conv5.shape[2:]
        pooled = [F.interpolate(branch(conv5), size, mode="bilinear", align_corners=False) for branch in self.ppm]
        logits = self.conv_last(torch.cat([conv5, *pooled], 1))
        if not deep_supervision:
            return logits
        return logits, self.conv_last_deepsup(self.dropout_deepsup(self.cbr_deepsup(features[-2])))


CLASSIFIER = "conv_last.4.weight"
"""The decoder's last layer (``conv_last[-1]``): its output channels are the classes."""


class SceneParser(nn.Module):
    """Encoder and decoder; their state dicts are the release's two files."""

    def __init__(self, net: Network, num_class: int) -> None:
        super().__init__()
        self.layout, self.num_class = net, num_class
        self.encoder = ResnetDilated(net)
        self.decoder = PPMDeepsup(net, num_class)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Class logits at 1/8 of the input's size."""
        return self.decoder(self.encoder(x))  # type: ignore[return-value]

    def forward_train(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Logits of the main and the deep-supervision head, both at 1/8."""
        return self.decoder(self.encoder(x), deep_supervision=True)  # type: ignore[return-value]


def init_weights(model: SceneParser, seed: int) -> SceneParser:
    """CSAIL's initialisation, seeded: He-normal convolutions (the ResNet's fan-out rule in
    the encoder, ``kaiming_normal_`` in the decoder), batch norms at weight 1 and bias 0
    (decoder: 1e-4)."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for part, bn_bias in ((model.encoder, 0.0), (model.decoder, 1e-4)):
            for m in part.modules():
                if isinstance(m, nn.Conv2d):
                    fan = m.kernel_size[0] * m.kernel_size[1] * (m.out_channels if part is model.encoder else m.in_channels)
                    m.weight.copy_(torch.randn(m.weight.shape, generator=generator) * (2.0 / fan) ** 0.5)
                    if m.bias is not None:
                        m.bias.zero_()
                elif isinstance(m, nn.BatchNorm2d):
                    m.weight.fill_(1.0)
                    m.bias.fill_(bn_bias)
    return model


def plain_batch_norm_state(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``state`` with what only CSAIL's synchronized batch norm and older torch differ in made plain.

    A batch norm is whatever holds a ``running_mean`` in the file: the file alone says
    them, so that the same state can be compared with every layout. Drops their
    :data:`SYNC_BN_BUFFERS` and supplies their ``num_batches_tracked`` (unused at
    inference) where the file has none; every other key is left as it is, for a strict
    load to check.
    """
    norms = {key.rpartition(".")[0] for key in state if key.rpartition(".")[2] == "running_mean"}
    plain = {}
    for key, value in state.items():
        owner, _, leaf = key.rpartition(".")
        if leaf in SYNC_BN_BUFFERS and owner in norms:
            continue
        plain[key] = value
    for name in norms:
        key = f"{name}.num_batches_tracked" if name else "num_batches_tracked"
        plain.setdefault(key, torch.zeros((), dtype=torch.long))
    return plain


def scale_sizes(shape: tuple[int, int], image_sizes: Sequence[int], max_size: int, padding: int) -> list[tuple[int, int]]:
    """The ``(height, width)`` each scale runs at, as CSAIL's ``TestDataset``: the shorter
    side to ``image_sizes[i]`` unless the longer would pass ``max_size``, each side then
    rounded *up* to a multiple of ``padding`` (the image is resized to it, not padded)."""
    h, w = shape
    sizes = []
    for short in image_sizes:
        scale = min(short / min(h, w), max_size / max(h, w))
        th, tw = int(h * scale), int(w * scale)
        sizes.append((max(padding, -(-th // padding) * padding), max(padding, -(-tw // padding) * padding)))
    return sizes


def to_input(rgb: np.ndarray, size: tuple[int, int], device: torch.device) -> torch.Tensor:
    """``(1, 3, H, W)`` network input: RGB / 255 resized bilinearly (antialiased, as PIL's
    bilinear resize is), then normalised by ImageNet's mean and std."""
    x = torch.from_numpy(np.ascontiguousarray(rgb)).to(device).permute(2, 0, 1)[None].float().div_(255.0)
    if tuple(x.shape[2:]) != tuple(size):
        x = F.interpolate(x, size, mode="bilinear", align_corners=False, antialias=True)
    mean = torch.tensor(MEAN, device=device).view(1, 3, 1, 1)
    std = torch.tensor(STD, device=device).view(1, 3, 1, 1)
    return (x - mean) / std


@torch.inference_mode()
def predict(model: SceneParser, rgb: np.ndarray, image_sizes: Sequence[int], max_size: int = 1000, padding: int = 8) -> torch.Tensor:
    """Class probabilities ``(C, H, W)`` of one ``(H, W, 3)`` uint8 image, as CSAIL's ``test.py``:
    at each scale the logits are upsampled bilinearly to the image's size and soft-maxed;
    the probabilities are averaged over the scales."""
    device = next(model.parameters()).device
    h, w = rgb.shape[:2]
    scores = None
    sizes = scale_sizes((h, w), image_sizes, max_size, padding)
    for size in sizes:
        logits = model(to_input(rgb, size, device))
        probs = F.interpolate(logits, (h, w), mode="bilinear", align_corners=False).softmax(dim=1)[0]
        scores = probs if scores is None else scores + probs
    assert scores is not None
    return scores / len(sizes)
