"""MiDaS v2.1 small (``MidasNet_small``) in plain torch, with the official module layout.

The official network (isl-org/MiDaS, ``midas/midas_net_custom.py``) is
``MidasNet_small(features=64, backbone="efficientnet_lite3", exportable=True,
non_negative=True, blocks={"expand": True})``:

* ``pretrained``: EfficientNet-Lite3 as ``geffnet``'s ``tf_efficientnet_lite3``
  (TF "SAME" padding on strided convolutions, BatchNorm eps 1e-3, ReLU6, no
  squeeze-excitation), cut into four stages: ``layer1`` = stem conv, BN, ReLU6 and
  blocks 0-1 (stride 4, 32 channels), ``layer2`` = block 2 (/8, 48), ``layer3`` =
  blocks 3-4 (/16, 136), ``layer4`` = blocks 5-6 (/32, 384);
* ``scratch``: a 3 x 3 conv per stage to ``features`` x (1, 2, 4, 8) channels
  (``layer{1-4}_rn``, no bias), four fusion blocks (``refinenet{4..1}``: residual conv
  units, x2 bilinear upsampling with ``align_corners=True``, a 1 x 1 ``out_conv``
  halving the channels where ``expand``) and the head ``output_conv`` (3 x 3 conv to
  ``features / 2``, x2 bilinear upsampling with ``align_corners=False``, 3 x 3 conv to
  32, ReLU, 1 x 1 conv to 1, ReLU).

:data:`V21_SMALL` builds exactly that: its ``state_dict`` has the official file's 482
keys and shapes, so ``midas_v21_small_256.pt`` loads strictly. :data:`LIGHT` is the
same family (same modules, same key names; narrower and shallower) for the weights
trained here. The output is relative inverse depth ("disparity" up to an unknown scale
and shift), ``(N, H, W)`` at the input's size.

Preprocessing is the official one (``run.py`` / ``midas/transforms.py``): RGB / 255,
resized with bicubic interpolation keeping the aspect ratio, each side a multiple of 32
and at most the network's size (``resize_method="upper_bound"``), then ImageNet mean and
std; the prediction is upsampled back to the image with bicubic interpolation
(``align_corners=False``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)
MULTIPLE = 32
"""Both sides of the network's input are multiples of this (the backbone's stride)."""
BN_EPS = 1e-3
"""TensorFlow's BatchNorm epsilon, which the tf_* EfficientNets keep."""


@dataclass(frozen=True)
class BlockStage:
    """One EfficientNet stage: ``repeats`` blocks of one kind (``"ds"`` depthwise-separable, ``"ir"`` inverted residual)."""

    kind: str
    repeats: int
    kernel: int
    stride: int
    expand: int
    channels: int


@dataclass(frozen=True)
class MidasSpec:
    """Widths and depths of a ``MidasNet_small``: the EfficientNet-Lite stem and 7 stages, and the decoder's widths."""

    stem: int
    stages: tuple[BlockStage, ...]
    features: int
    head: int = 32
    input_size: int = 256
    """The network's side (the upper bound of the preprocessing resize)."""

    def __post_init__(self) -> None:
        if len(self.stages) != 7:
            raise ValueError("a MiDaS-small backbone has 7 EfficientNet stages")

    @property
    def stage_channels(self) -> tuple[int, int, int, int]:
        """Channels of ``pretrained.layer1..4`` (strides 4, 8, 16, 32)."""
        s = self.stages
        return (s[1].channels, s[2].channels, s[4].channels, s[6].channels)


LITE_LAYOUT = (("ds", 3, 1), ("ir", 3, 2), ("ir", 5, 2), ("ir", 3, 2), ("ir", 5, 1), ("ir", 5, 2), ("ir", 3, 1))
"""EfficientNet-Lite's 7 stages: block kind, kernel and stride, the same at every width and depth."""


def lite_stages(repeats: Sequence[int], expand: int, channels: Sequence[int]) -> tuple[BlockStage, ...]:
    """The 7 stages of :data:`LITE_LAYOUT` with these depths, widths and expansion (the depthwise-separable stage expands by 1)."""
    layout = zip(LITE_LAYOUT, repeats, channels, strict=True)
    return tuple(BlockStage(kind, n, kernel, stride, 1 if kind == "ds" else expand, c) for (kind, kernel, stride), n, c in layout)


V21_SMALL = MidasSpec(
    stem=32,
    stages=lite_stages(repeats=(1, 3, 3, 5, 5, 6, 1), expand=6, channels=(24, 32, 48, 96, 136, 232, 384)),
    features=64,
    head=32,
    input_size=256,
)
"""MiDaS v2.1 small: EfficientNet-Lite3 (width 1.2, depth 1.4 of Lite0's arch) and a 64-feature decoder."""

LIGHT = MidasSpec(
    stem=16,
    stages=lite_stages(repeats=(1, 1, 2, 2, 2, 2, 1), expand=4, channels=(8, 16, 24, 48, 64, 96, 128)),
    features=16,
    head=16,
    input_size=256,
)
"""The light network trained here: same modules and key names, about 1/15 of the parameters."""

NETWORKS = {"light": LIGHT, "v21-small": V21_SMALL}


# ---------------------------------------------------------------------- backbone


class Conv2dSame(nn.Conv2d):
    """``nn.Conv2d`` with TensorFlow's "SAME" padding, computed for each input size (geffnet's ``Conv2dSame``).

    For an input side ``i``, kernel ``k`` and stride ``s`` the output has ``ceil(i / s)``
    pixels and the padding ``max((ceil(i / s) - 1) s + k - i, 0)`` is split with the odd
    pixel at the end (right, bottom), where PyTorch's symmetric padding would shift the
    sampling grid by half a step.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, stride: int = 1, groups: int = 1, bias: bool = False):
        super().__init__(in_channels, out_channels, kernel_size, stride, 0, 1, groups, bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        ih, iw = x.shape[-2:]
        (kh, kw), (sh, sw) = self.kernel_size, self.stride
        ph = max((math.ceil(ih / sh) - 1) * sh + kh - ih, 0)
        pw = max((math.ceil(iw / sw) - 1) * sw + kw - iw, 0)
        if ph or pw:
            x = F.pad(x, [pw // 2, pw - pw // 2, ph // 2, ph - ph // 2])
        return F.conv2d(x, self.weight, self.bias, self.stride, 0, self.dilation, self.groups)


def _conv(cin: int, cout: int, kernel: int, stride: int = 1, groups: int = 1) -> nn.Conv2d:
    """A bias-free conv with TF "SAME" padding (static and symmetric where the stride is 1, as geffnet builds it)."""
    if stride == 1:
        return nn.Conv2d(cin, cout, kernel, 1, (kernel - 1) // 2, groups=groups, bias=False)
    return Conv2dSame(cin, cout, kernel, stride, groups=groups)


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, eps=BN_EPS)


class DepthwiseSeparableConv(nn.Module):
    """geffnet's ``DepthwiseSeparableConv`` without squeeze-excitation: dw conv, BN, ReLU6, pw conv, BN."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int) -> None:
        super().__init__()
        self.has_residual = stride == 1 and cin == cout
        self.conv_dw = _conv(cin, cin, kernel, stride, groups=cin)
        self.bn1 = _bn(cin)
        self.act1 = nn.ReLU6(inplace=True)
        self.se = nn.Identity()
        self.conv_pw = _conv(cin, cout, 1)
        self.bn2 = _bn(cout)
        self.act2 = nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.act2(self.bn2(self.conv_pw(self.se(self.act1(self.bn1(self.conv_dw(x)))))))
        return y + x if self.has_residual else y


class InvertedResidual(nn.Module):
    """geffnet's ``InvertedResidual`` without squeeze-excitation: pw expand, BN, ReLU6, dw conv, BN, ReLU6, pw project, BN."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = make_divisible(cin * expand)
        self.has_residual = stride == 1 and cin == cout
        self.conv_pw = _conv(cin, mid, 1)
        self.bn1 = _bn(mid)
        self.act1 = nn.ReLU6(inplace=True)
        self.conv_dw = _conv(mid, mid, kernel, stride, groups=mid)
        self.bn2 = _bn(mid)
        self.act2 = nn.ReLU6(inplace=True)
        self.se = nn.Identity()
        self.conv_pwl = _conv(mid, cout, 1)
        self.bn3 = _bn(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.act1(self.bn1(self.conv_pw(x)))
        y = self.se(self.act2(self.bn2(self.conv_dw(y))))
        y = self.bn3(self.conv_pwl(y))
        return y + x if self.has_residual else y


def make_divisible(v: float, divisor: int = 8) -> int:
    """geffnet's channel rounding: to the nearest multiple of 8, never below 90% of ``v``."""
    new = max(divisor, int(v + divisor / 2) // divisor * divisor)
    return new + divisor if new < 0.9 * v else new


def _blocks(spec: MidasSpec) -> list[nn.Sequential]:
    blocks, cin = [], spec.stem
    for stage in spec.stages:
        seq = []
        for r in range(stage.repeats):
            stride = stage.stride if r == 0 else 1
            if stage.kind == "ds":
                seq.append(DepthwiseSeparableConv(cin, stage.channels, stage.kernel, stride))
            else:
                seq.append(InvertedResidual(cin, stage.channels, stage.kernel, stride, stage.expand))
            cin = stage.channels
        blocks.append(nn.Sequential(*seq))
    return blocks


class EfficientNetStages(nn.Module):
    """MiDaS's ``pretrained``: ``_make_efficientnet_backbone`` of an EfficientNet-Lite, four stages."""

    def __init__(self, spec: MidasSpec) -> None:
        super().__init__()
        b = _blocks(spec)
        self.layer1 = nn.Sequential(_conv(3, spec.stem, 3, 2), _bn(spec.stem), nn.ReLU6(inplace=True), b[0], b[1])
        self.layer2 = nn.Sequential(b[2])
        self.layer3 = nn.Sequential(b[3], b[4])
        self.layer4 = nn.Sequential(b[5], b[6])

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        l1 = self.layer1(x)
        l2 = self.layer2(l1)
        l3 = self.layer3(l2)
        return [l1, l2, l3, self.layer4(l3)]


# ---------------------------------------------------------------------- decoder


class ResidualConvUnit(nn.Module):
    """MiDaS's ``ResidualConvUnit_custom`` (no BN): ``x + conv2(relu(conv1(relu(x))))``."""

    def __init__(self, features: int, activation: nn.Module) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(features, features, 3, 1, 1, bias=True)
        self.conv2 = nn.Conv2d(features, features, 3, 1, 1, bias=True)
        self.activation = activation

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv2(self.activation(self.conv1(self.activation(x)))) + x


class FeatureFusionBlock(nn.Module):
    """MiDaS's ``FeatureFusionBlock_custom``: add the skip's residual unit, a residual unit, x2 bilinear (corners aligned), 1 x 1 conv."""

    def __init__(self, features: int, activation: nn.Module, expand: bool) -> None:
        super().__init__()
        self.out_conv = nn.Conv2d(features, features // 2 if expand else features, 1, 1, 0, bias=True)
        self.resConfUnit1 = ResidualConvUnit(features, activation)
        self.resConfUnit2 = ResidualConvUnit(features, activation)

    def forward(self, x: torch.Tensor, skip: torch.Tensor | None = None) -> torch.Tensor:
        if skip is not None:
            x = x + self.resConfUnit1(skip)
        x = self.resConfUnit2(x)
        x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=True)
        return self.out_conv(x)


class Interpolate(nn.Module):
    """MiDaS's ``Interpolate`` module (x2 bilinear, ``align_corners=False`` in the v2.1 head)."""

    def __init__(self, scale_factor: float, mode: str) -> None:
        super().__init__()
        self.scale_factor, self.mode = scale_factor, mode

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.interpolate(x, scale_factor=self.scale_factor, mode=self.mode, align_corners=False)


class Scratch(nn.Module):
    """MiDaS's ``scratch``: stage projections, fusion blocks and the output head."""

    def __init__(self, spec: MidasSpec) -> None:
        super().__init__()
        f = spec.features
        widths = (f, 2 * f, 4 * f, 8 * f)  # expand=True
        for i, (cin, cout) in enumerate(zip(spec.stage_channels, widths), start=1):
            setattr(self, f"layer{i}_rn", nn.Conv2d(cin, cout, 3, 1, 1, bias=False))
        self.activation = nn.ReLU(False)
        self.refinenet4 = FeatureFusionBlock(widths[3], self.activation, expand=True)
        self.refinenet3 = FeatureFusionBlock(widths[2], self.activation, expand=True)
        self.refinenet2 = FeatureFusionBlock(widths[1], self.activation, expand=True)
        self.refinenet1 = FeatureFusionBlock(widths[0], self.activation, expand=False)
        self.output_conv = nn.Sequential(
            nn.Conv2d(f, f // 2, 3, 1, 1),
            Interpolate(scale_factor=2, mode="bilinear"),
            nn.Conv2d(f // 2, spec.head, 3, 1, 1),
            self.activation,
            nn.Conv2d(spec.head, 1, 1, 1, 0),
            nn.ReLU(True),  # non_negative
            nn.Identity(),
        )


class MidasNet(nn.Module):
    """``MidasNet_small`` of a :class:`MidasSpec`: ``(N, 3, H, W)`` normalised RGB to ``(N, H, W)`` relative inverse depth.

    ``H`` and ``W`` must be multiples of 32 (:func:`network_size` chooses them).
    """

    def __init__(self, spec: MidasSpec = V21_SMALL) -> None:
        super().__init__()
        self.spec = spec
        self.pretrained = EfficientNetStages(spec)
        self.scratch = Scratch(spec)

    def forward(self, x: torch.Tensor, *, raw: bool = False) -> torch.Tensor:
        """The prediction; ``raw``: before the final ReLU (for training)."""
        l1, l2, l3, l4 = self.pretrained(x)
        s = self.scratch
        path = s.refinenet4(s.layer4_rn(l4))
        path = s.refinenet3(path, s.layer3_rn(l3))
        path = s.refinenet2(path, s.layer2_rn(l2))
        path = s.refinenet1(path, s.layer1_rn(l1))
        head = s.output_conv[:5] if raw else s.output_conv
        return head(path).squeeze(1)


def init_weights(net: MidasNet, seed: int) -> MidasNet:
    """Seeded initialisation for training from scratch (no pretrained weights exist here).

    Backbone: geffnet's (He-normal over fan-out, BN at 1 / 0), with the last BN of every
    residual block at zero so that the block starts as the identity. Decoder, which has
    no normalisation: variance-preserving fan-in normals (x 2 before a ReLU), the second
    conv of every residual unit at zero (each unit starts as the identity), and the last
    1 x 1 conv small with a positive bias, so the final ReLU starts open everywhere.
    With He normals in the decoder too, its activations reached several hundred at
    initialisation and the final ReLU closed for good within a few dozen steps.
    """
    generator = torch.Generator().manual_seed(seed)

    def normal(conv: nn.Conv2d, std: float) -> None:
        conv.weight.normal_(0.0, std, generator=generator)
        if conv.bias is not None:
            conv.bias.zero_()

    def fan_in(conv: nn.Conv2d) -> int:
        return conv.in_channels // conv.groups * conv.kernel_size[0] * conv.kernel_size[1]

    with torch.no_grad():
        for module in net.pretrained.modules():
            if isinstance(module, nn.Conv2d):
                fan_out = module.out_channels // module.groups * module.kernel_size[0] * module.kernel_size[1]
                normal(module, math.sqrt(2.0 / fan_out))
            elif isinstance(module, nn.BatchNorm2d):
                module.weight.fill_(1.0)
                module.bias.zero_()
            elif isinstance(module, (InvertedResidual, DepthwiseSeparableConv)) and module.has_residual:
                last = module.bn3 if isinstance(module, InvertedResidual) else module.bn2
                last.weight.zero_()
        for module in net.scratch.modules():
            if isinstance(module, nn.Conv2d):
                normal(module, math.sqrt(1.0 / fan_in(module)))
            elif isinstance(module, ResidualConvUnit):
                normal(module.conv1, math.sqrt(2.0 / fan_in(module.conv1)))
                normal(module.conv2, 0.0)
        head = net.scratch.output_conv
        normal(head[2], math.sqrt(2.0 / fan_in(head[2])))
        normal(head[4], 0.01)
        head[4].bias.fill_(1.0)
    return net


# ---------------------------------------------------------------------- pre- and post-processing


def network_size(height: int, width: int, bound: int) -> tuple[int, int]:
    """MiDaS's ``Resize(bound, bound, keep_aspect_ratio=True, ensure_multiple_of=32, resize_method="upper_bound")``: ``(h, w)``."""
    scale = min(bound / height, bound / width)

    def multiple(x: float) -> int:
        y = int(np.round(x / MULTIPLE) * MULTIPLE)
        if y > bound:
            y = int(np.floor(x / MULTIPLE) * MULTIPLE)
        return max(y, MULTIPLE)

    return multiple(scale * height), multiple(scale * width)


def preprocess(images: np.ndarray | Sequence[np.ndarray], bound: int) -> torch.Tensor:
    """``(N, H, W, 3)`` uint8 RGB (one size) to the network's ``(N, 3, h, w)`` input, as MiDaS's transforms do."""
    images = [np.asarray(im) for im in images]
    h, w = network_size(*images[0].shape[:2], bound)
    batch = np.empty((len(images), 3, h, w), dtype=np.float32)
    mean, std = np.asarray(MEAN, np.float32), np.asarray(STD, np.float32)
    for i, im in enumerate(images):
        x = im.astype(np.float32) / 255.0
        if x.shape[:2] != (h, w):
            x = cv2.resize(x, (w, h), interpolation=cv2.INTER_CUBIC)
        batch[i] = ((x - mean) / std).transpose(2, 0, 1)
    return torch.from_numpy(batch)


def predict(net: MidasNet, images: np.ndarray | Sequence[np.ndarray], device: torch.device | str = "cpu") -> np.ndarray:
    """Relative inverse depth ``(N, H, W)`` float32 of same-sized uint8 RGB images, at the images' size."""
    images = [np.asarray(im) for im in images]
    h, w = images[0].shape[:2]
    x = preprocess(images, net.spec.input_size).to(device)
    with torch.inference_mode():
        out = net(x)
        if out.shape[-2:] != (h, w):
            out = F.interpolate(out[:, None], size=(h, w), mode="bicubic", align_corners=False)[:, 0]
    return out.float().cpu().numpy()
