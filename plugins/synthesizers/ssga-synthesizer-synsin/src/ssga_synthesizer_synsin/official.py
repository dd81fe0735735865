"""SynSin's official network, key for key: the ``zbuffer_pts`` model of the MP3D recipe, for inference with ``mp3d/synsin.pth``.

``train.sh``'s ``resnet_256W8UpDown64`` encoder and decoder, ``norm_G sync:spectral_batch``
and the 32-filter ``Unet`` depth regressor. Spectral norm is folded into plain weights when
the file loads (:func:`official_state_dict`), and the BigGAN-style noise of its
normalisation layers is drawn from a generator seeded with 0 on every call (SynSin's demo
resets the global seed to 0 before each render). What it shares with the light network
(the render, the options) is in :mod:`.model`.
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Iterable, Mapping
from typing import Any

import torch
from torch import nn

from ssga_synthesizer_synsin.model import RenderOptions, depth_from_logits, pad_to
from ssga_synthesizer_synsin.splat import Splat

OFFICIAL_PREFIX = "model.module."
"""SynSin wraps its model in ``BaseModel`` (attribute ``model``) around ``nn.DataParallel`` (``module``)."""

DROPPED_PREFIXES = ("model.module.loss_function.", "netD.")
"""Training-only modules in the official checkpoints, dropped when loading: the perceptual
loss's VGG19 (``SynthesisLoss``) and the discriminator (``BaseModel.netD``)."""


class _StandingBN(nn.Module):
    """SynSin's ``bn`` (from BigGAN): batch norm whose gain and bias come from outside; eval uses the stored stats."""

    def __init__(self, channels: int, eps: float = 1e-5) -> None:
        super().__init__()
        self.eps = eps
        self.register_buffer("stored_mean", torch.zeros(channels))
        self.register_buffer("stored_var", torch.ones(channels))
        self.register_buffer("accumulation_counter", torch.zeros(1))

    def forward(self, x: torch.Tensor, gain: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        if self.training:
            mean = x.mean((0, 2, 3), keepdim=True)
            var = (x * x).mean((0, 2, 3), keepdim=True) - mean * mean
        else:
            mean, var = self.stored_mean.view(1, -1, 1, 1), self.stored_var.view(1, -1, 1, 1)
        scale = torch.rsqrt(var + self.eps) * gain
        return x * scale - (mean * scale - bias)


class _LinearNoiseLayer(nn.Module):
    """SynSin's ``LinearNoiseLayer``: batch norm with gain and bias predicted from 20 noise values."""

    noise_size = 20

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.gain = nn.Linear(self.noise_size, channels, bias=False)
        self.bias = nn.Linear(self.noise_size, channels, bias=False)
        self.bn = _StandingBN(channels)
        self.generator: torch.Generator | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        noise = torch.randn(
            x.shape[0],
            self.noise_size,
            generator=self.generator,
            device=x.device if self.generator is None else self.generator.device,
        ).to(x)
        gain = (1 + self.gain(noise)).view(x.shape[0], -1, 1, 1)
        bias = self.bias(noise).view(x.shape[0], -1, 1, 1)
        return self.bn(x, gain, bias)


class _Identity(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x


class _ResNetBlock(nn.Module):
    """SynSin's ``ResNet_Block`` (``models/layers/blocks.py``), Sequential indices and all."""

    def __init__(self, cin: int, cout: int, resample: str | bool = False) -> None:
        super().__init__()
        if resample == "Up":
            scale: nn.Module = nn.Upsample(scale_factor=2, mode="bilinear")
        elif resample:
            scale = nn.AvgPool2d(kernel_size=3, stride=2, padding=1)
        else:
            scale = _Identity()
        self.ch_a = nn.Sequential(
            _LinearNoiseLayer(cin),
            nn.ReLU(),
            nn.Conv2d(cin, cout, 3, 1, 1),
            _LinearNoiseLayer(cout),
            nn.ReLU(),
            nn.Conv2d(cout, cout, 3, 1, 1),
            scale,
        )
        self.ch_b = nn.Sequential(nn.Conv2d(cin, cout, 1, 1, 0), scale) if resample or cin != cout else _Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.ch_a(x) + self.ch_b(x)


def _resnet_256w8updown64(ngf: int) -> tuple[list[int], list[int], list[str | bool]]:
    """``models/networks/configs.py``, setup ``256W8UpDown64``: encoder widths, decoder widths, decoder resampling."""
    enc = [3, ngf // 2, ngf // 2, ngf // 2, ngf, ngf, ngf, ngf, 64]
    dec = [64, ngf, ngf * 2, ngf * 4, ngf * 4, ngf * 2, ngf * 2, ngf * 2, 3]
    up: list[str | bool] = [False, "Down", "Down", False, "Up", "Up", False, False]
    return enc, dec, up


class _ResNetEncoder(nn.Module):
    def __init__(self, widths: list[int]) -> None:
        super().__init__()
        self.gblocks = nn.Sequential(*(_ResNetBlock(a, b) for a, b in itertools.pairwise(widths)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.gblocks(x)


class _ResNetDecoder(nn.Module):
    def __init__(self, widths: list[int], resample: list[str | bool]) -> None:
        super().__init__()
        self.eblocks = nn.Sequential(*(_ResNetBlock(a, b, r) for a, b, r in zip(widths[:-1], widths[1:], resample)))
        self.norm = nn.Tanh()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.norm(self.eblocks(x))


class _OfficialUnet(nn.Module):
    """SynSin's ``Unet`` (``models/networks/architectures.py``): eight stride-2 4 x 4 convolutions down, eight up."""

    def __init__(self, num_filters: int = 32, channels_in: int = 3, channels_out: int = 1) -> None:
        super().__init__()
        f = num_filters
        downs = [(channels_in, f), (f, f * 2), (f * 2, f * 4), (f * 4, f * 8)] + [(f * 8, f * 8)] * 4
        for i, (a, b) in enumerate(downs, 1):
            setattr(self, f"conv{i}", nn.Conv2d(a, b, 4, 2, 1))
        ups = [(f * 8, f * 8)] + [(f * 16, f * 8)] * 3 + [(f * 16, f * 4), (f * 8, f * 2), (f * 4, f), (f * 2, channels_out)]
        for i, (a, b) in enumerate(ups, 1):
            setattr(self, f"dconv{i}", nn.Conv2d(a, b, 3, 1, 1))
        self.batch_norm = nn.BatchNorm2d(f)
        for name, c in (("2_0", 2), ("2_1", 2), ("4_0", 4), ("4_1", 4)):
            setattr(self, f"batch_norm{name}", nn.BatchNorm2d(f * c))
        for i in range(8):
            setattr(self, f"batch_norm8_{i}", nn.BatchNorm2d(f * 8))
        self.up = nn.Upsample(scale_factor=2, mode="bilinear")
        self.leaky_relu = nn.LeakyReLU(0.2)
        self.relu = nn.ReLU()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        lrelu, relu, up = self.leaky_relu, self.relu, self.up
        e1 = self.conv1(x)
        e2 = self.batch_norm2_0(self.conv2(lrelu(e1)))
        e3 = self.batch_norm4_0(self.conv3(lrelu(e2)))
        e4 = self.batch_norm8_0(self.conv4(lrelu(e3)))
        e5 = self.batch_norm8_1(self.conv5(lrelu(e4)))
        e6 = self.batch_norm8_2(self.conv6(lrelu(e5)))
        e7 = self.batch_norm8_3(self.conv7(lrelu(e6)))
        e8 = self.conv8(lrelu(e7))
        d1 = torch.cat((self.batch_norm8_4(self.dconv1(up(relu(e8)))), e7), 1)
        d2 = torch.cat((self.batch_norm8_5(self.dconv2(up(relu(d1)))), e6), 1)
        d3 = torch.cat((self.batch_norm8_6(self.dconv3(up(relu(d2)))), e5), 1)
        d4 = torch.cat((self.batch_norm8_7(self.dconv4(up(relu(d3)))), e4), 1)
        d5 = torch.cat((self.batch_norm4_1(self.dconv5(up(relu(d4)))), e3), 1)
        d6 = torch.cat((self.batch_norm2_1(self.dconv6(up(relu(d5)))), e2), 1)
        d7 = torch.cat((self.batch_norm(self.dconv7(up(relu(d6)))), e1), 1)
        return self.dconv8(up(relu(d7)))


class _PtsManipulator(nn.Module):
    """Holds the official ``pts_transformer``'s state: the NDC pixel grid and the (unused) default feature."""

    def __init__(self, width: int, channels: int = 64) -> None:
        super().__init__()
        self.splatter = nn.Module()
        self.splatter.register_parameter("default_feature", nn.Parameter(torch.randn(1, channels, 1)))
        xs = (torch.linspace(0, width - 1, width) / float(width - 1) * 2 - 1).view(1, 1, 1, width).repeat(1, 1, width, 1)
        ys = (torch.linspace(0, width - 1, width) / float(width - 1) * 2 - 1).view(1, 1, width, 1).repeat(1, 1, 1, width)
        self.register_buffer("xyzs", torch.cat((xs, -ys, -torch.ones(xs.size()), torch.ones(xs.size())), 1).view(1, 4, -1))


class SynSin(nn.Module):
    """SynSin's ``ZbufferModelPts`` with the MP3D recipe's parts, for inference (see the module docstring)."""

    def __init__(self, options: RenderOptions | None = None, *, ngf: int = 64, width: int = 256, voxel_size: int = 64) -> None:
        super().__init__()
        self.render_options = options or RenderOptions()
        enc, dec, resample = _resnet_256w8updown64(ngf)
        self.encoder = _ResNetEncoder(enc)
        self.pts_regressor = _OfficialUnet(32, 3, 1)
        self.pts_transformer = _PtsManipulator(width, enc[-1])
        self.projector = _ResNetDecoder(dec, resample)
        self.register_buffer("min_z", torch.tensor([0.1]))  # as in ZbufferModelPts (unused by its forward)
        self.register_buffer("max_z", torch.tensor([self.render_options.max_z]))
        self.register_buffer("discretized_zs", torch.linspace(self.render_options.min_z, self.render_options.max_z, voxel_size))

    @property
    def options(self) -> RenderOptions:
        return self.render_options

    def _seed(self, part: nn.Module, device: torch.device) -> None:
        # One generator per call, shared by the part's noise layers in forward order (not thread-safe
        # across concurrent calls on one network: the synthesizer renders views one at a time).
        generator = torch.Generator(device=device).manual_seed(0)
        for m in part.modules():
            if isinstance(m, _LinearNoiseLayer):
                m.generator = generator

    def depth(self, img: torch.Tensor) -> torch.Tensor:
        x, (h, w) = pad_to(img, 256)
        return depth_from_logits(self.pts_regressor(x)[..., :h, :w], self.options)

    def features(self, img: torch.Tensor) -> torch.Tensor:
        self._seed(self.encoder, img.device)
        return self.encoder(img)

    def refine(self, s: Splat) -> torch.Tensor:
        self._seed(self.projector, s.features.device)
        x, (h, w) = pad_to(s.features, 4)
        return self.projector(x)[..., :h, :w]


def spectral_weight(weight_orig: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """The weight ``torch.nn.utils.spectral_norm`` uses in eval mode: ``W / (u . W_mat v)`` (no power iteration)."""
    w = weight_orig.reshape(weight_orig.shape[0], -1)
    sigma = torch.dot(u, torch.mv(w, v))
    return weight_orig / sigma


def official_state_dict(state: Mapping[str, Any], own: Iterable[str]) -> tuple[dict[str, Any], dict[str, int]]:
    """An official SynSin state dict in :class:`SynSin`'s key layout (``own``: its keys), and what was done to it.

    * keys lose the ``model.module.`` prefix (``BaseModel`` around ``nn.DataParallel``);
    * keys under :data:`DROPPED_PREFIXES` (the VGG19 perceptual loss, the discriminator)
      are dropped: training-only modules, the one documented exception to strict loading;
    * spectral-norm triples ``X.weight_orig``, ``X.weight_u``, ``X.weight_v`` become
      ``X.weight`` (:func:`spectral_weight`), the weight the official model computes;
    * BatchNorm's ``num_batches_tracked`` is added where the file lacks it (files saved by
      torch < 0.4.1; its value does not matter in eval mode).

    Everything else passes unchanged, so the strict load that follows names any other
    difference. Returns the mapped dict and counts (``dropped``, ``spectral``, ``filled``).
    """
    out: dict[str, Any] = {}
    counts = {"dropped": 0, "spectral": 0, "filled": 0}
    for key, value in state.items():
        if key.startswith(DROPPED_PREFIXES):
            counts["dropped"] += 1
            continue
        out[key.removeprefix(OFFICIAL_PREFIX)] = value
    for key in [k for k in out if k.endswith(".weight_orig")]:
        base = key[: -len("_orig")]
        u, v = out.get(base + "_u"), out.get(base + "_v")
        if isinstance(u, torch.Tensor) and isinstance(v, torch.Tensor) and isinstance(out[key], torch.Tensor):
            out[base] = spectral_weight(out.pop(key).float(), out.pop(base + "_u").float(), out.pop(base + "_v").float())
            counts["spectral"] += 1
    for key in own:
        if key.endswith(".num_batches_tracked") and key not in out and key.replace("num_batches_tracked", "running_mean") in out:
            out[key] = torch.zeros((), dtype=torch.long)  # as BatchNorm registers it
            counts["filled"] += 1
    return out, counts


def options_from_opts(opts: Any) -> RenderOptions:
    """The renderer settings of a pickled SynSin ``opts`` (an ``argparse.Namespace``), defaults where absent."""
    base = RenderOptions()
    get = (
        (lambda k, d: getattr(opts, k, d))
        if isinstance(opts, argparse.Namespace)
        else (lambda k, d: opts.get(k, d) if isinstance(opts, Mapping) else d)
    )
    return RenderOptions(
        radius=float(get("radius", base.radius)),
        points_per_pixel=int(get("pp_pixel", base.points_per_pixel)),
        tau=float(get("tau", base.tau)),
        rad_pow=float(get("rad_pow", base.rad_pow)),
        min_z=float(get("min_z", base.min_z)),
        max_z=float(get("max_z", base.max_z)),
    )
