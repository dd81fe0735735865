"""The SynSin networks in plain torch: what both share, and the light one trained here (the official layout: :mod:`.official`).

Both networks (the official layout is :class:`~.official.SynSin`) have SynSin's three parts under
SynSin's module names (``models/z_buffermodel.py``):

* ``pts_regressor``: depth from the image, ``sigmoid(net(img)) * (max_z - min_z) + min_z``;
* ``encoder``: per-pixel features from the image;
* ``projector``: the refinement network, from splatted features to the target image;

with the point cloud moved and splatted in between by :func:`render` (:mod:`.splat`).
Images are RGB in ``[-1, 1]`` (mean = std = 0.5, SynSin's ``--normalize_image``).

:class:`SynSinLight` is this package's network, small enough to train on a CPU: the same
parts, narrower, with three departures that a short training needs (each measured in the
README): the depth U-Net runs at half resolution with two coordinate channels (a level
camera's floor depth depends on the image row); the splatted features include the RGB
colours; and the refinement predicts a residual over the splatted colours (its last layer
starts at zero, so an untrained network already renders the splat).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ssga_synthesizer_synsin.splat import Splat, splat

# ----------------------------------------------------------------------------- shared


@dataclass(frozen=True)
class RenderOptions:
    """SynSin's renderer settings (``options/train_options.py``) and the depth range."""

    radius: float = 4.0
    points_per_pixel: int = 128
    tau: float = 1.0
    rad_pow: float = 2.0
    min_z: float = 0.5
    max_z: float = 10.0


def normalise(rgb: np.ndarray) -> torch.Tensor:
    """``(H, W, 3)`` or ``(N, H, W, 3)`` uint8 to ``(N, 3, H, W)`` float in ``[-1, 1]``."""
    x = torch.from_numpy(np.ascontiguousarray(rgb))
    if x.ndim == 3:
        x = x[None]
    return x.permute(0, 3, 1, 2).float().div(127.5).sub(1.0)


def to_uint8(img: torch.Tensor) -> np.ndarray:
    """``(N, 3, H, W)`` in ``[-1, 1]`` to ``(N, H, W, 3)`` uint8."""
    return ((img.clamp(-1, 1) + 1.0) * 127.5).round().byte().permute(0, 2, 3, 1).cpu().numpy()


def pad_to(x: torch.Tensor, multiple: int) -> tuple[torch.Tensor, tuple[int, int]]:
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
    return x, (h, w)


def move_points(depth: torch.Tensor, K: torch.Tensor, T: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Where each pixel lands in the same camera moved by ``T`` (target <- source), with its depth there.

    The core's conventions (``ssga_core.geometry``: OpenCV camera frame, planar depth, pixel
    centres at integers): ``X = z K^-1 [u, v, 1]``, ``X' = R X + t``, ``(u', v') = K X' / z'``.

    Args:
        depth: ``(B, 1, H, W)`` planar depths.
        K: ``(3, 3)`` or ``(B, 3, 3)`` intrinsics.
        T: ``(B, 4, 4)`` transforms taking source camera points into the target camera.

    Returns:
        ``(B, H * W, 2)`` pixel positions (row by row) and ``(B, H * W)`` target depths.
    """
    b, _, h, w = depth.shape
    K = K.to(depth).expand(b, 3, 3)
    T = T.to(depth)
    v, u = torch.meshgrid(
        torch.arange(h, dtype=depth.dtype, device=depth.device),
        torch.arange(w, dtype=depth.dtype, device=depth.device),
        indexing="ij",
    )
    pix = torch.stack([u.reshape(-1), v.reshape(-1), torch.ones(h * w, dtype=depth.dtype, device=depth.device)])  # (3, HW)
    rays = torch.linalg.solve(K, pix.expand(b, 3, h * w))  # K^-1 [u, v, 1]
    points = rays * depth.reshape(b, 1, h * w)
    moved = T[:, :3, :3] @ points + T[:, :3, 3:]
    q = K @ moved
    z = q[:, 2]
    safe = torch.where(z > 0, z, torch.ones_like(z))
    uv = torch.stack([q[:, 0] / safe, q[:, 1] / safe], dim=-1)
    uv = torch.where((z > 0)[..., None], uv, torch.full_like(uv, float("nan")))
    return uv, z


def render(
    net: nn.Module, images: torch.Tensor, K: torch.Tensor, T: torch.Tensor, *, depth: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor, Splat]:
    """One image per source, rendered at its target: ``(images_out, depth, splat)``.

    ``net`` is a :class:`SynSin` or :class:`SynSinLight`; ``depth`` overrides the predicted one
    (SynSin's ``--use_gt_depth``). Differentiable in the network's parameters.
    """
    if depth is None:
        depth = net.depth(images)
    feats = net.features(images)
    uv, z = move_points(depth, K, T)
    h, w = feats.shape[-2:]
    o = net.options
    s = splat(
        uv,
        z,
        feats.flatten(2).transpose(1, 2),
        (h, w),
        radius=o.radius,
        points_per_pixel=o.points_per_pixel,
        tau=o.tau,
        rad_pow=o.rad_pow,
    )
    return net.refine(s), depth, s


def depth_from_logits(logits: torch.Tensor, options: RenderOptions) -> torch.Tensor:
    return torch.sigmoid(logits) * (options.max_z - options.min_z) + options.min_z


# ----------------------------------------------------------------------------- light network

LIGHT_DEPTH_WIDTHS = (16, 32, 48, 64, 96)
LIGHT_REFINE_WIDTHS = (16, 32, 48, 64)
LIGHT_FEATURES = 13
"""Learned feature channels; with the 3 colour channels each point carries 16."""


@dataclass(frozen=True)
class LightOptions:
    """The light network's shape and renderer (stored in its checkpoints as ``opts``)."""

    depth_widths: tuple[int, ...] = LIGHT_DEPTH_WIDTHS
    refine_widths: tuple[int, ...] = LIGHT_REFINE_WIDTHS
    features: int = LIGHT_FEATURES
    render: RenderOptions = field(default_factory=lambda: RenderOptions(radius=1.5, points_per_pixel=8))

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> LightOptions:
        return cls(
            depth_widths=tuple(data["depth_widths"]),
            refine_widths=tuple(data["refine_widths"]),
            features=int(data["features"]),
            render=RenderOptions(**data["render"]),
        )


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, stride, 1)


class _UNet(nn.Module):
    """A plain U-Net: stride-2 convolutions down, bilinear upsampling and skip concatenation up."""

    def __init__(self, cin: int, cout: int, widths: tuple[int, ...]) -> None:
        super().__init__()
        self.inc = _conv(cin, widths[0])
        self.down = nn.ModuleList(
            nn.Sequential(_conv(a, b, 2), nn.ReLU(inplace=True), _conv(b, b), nn.ReLU(inplace=True))
            for a, b in itertools.pairwise(widths)
        )
        self.up = nn.ModuleList(nn.Sequential(_conv(b + a, a), nn.ReLU(inplace=True)) for a, b in itertools.pairwise(widths))
        self.out = nn.Conv2d(widths[0], cout, 3, 1, 1)
        self.multiple = 2 ** (len(widths) - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = [F.relu(self.inc(x))]
        for down in self.down:
            skips.append(down(skips[-1]))
        y = skips.pop()
        for up in reversed(self.up):
            skip = skips.pop()
            y = F.interpolate(y, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = up(torch.cat([y, skip], 1))
        return self.out(y)


def _coords(x: torch.Tensor) -> torch.Tensor:
    b, _, h, w = x.shape
    ys = torch.linspace(-1, 1, h, dtype=x.dtype, device=x.device).view(1, 1, h, 1).expand(b, 1, h, w)
    xs = torch.linspace(-1, 1, w, dtype=x.dtype, device=x.device).view(1, 1, 1, w).expand(b, 1, h, w)
    return torch.cat([x, ys, xs], 1)


class SynSinLight(nn.Module):
    """The light SynSin trained on procedural homes (see the module docstring)."""

    def __init__(self, options: LightOptions | None = None) -> None:
        super().__init__()
        self.light = options or LightOptions()
        o = self.light
        self.pts_regressor = _UNet(5, 1, o.depth_widths)
        self.encoder = nn.Sequential(_conv(3, 16), nn.ReLU(inplace=True), _conv(16, o.features))
        self.projector = _UNet(3 + o.features + 1, 3, o.refine_widths)
        nn.init.zeros_(self.projector.out.weight)
        nn.init.zeros_(self.projector.out.bias)

    @property
    def options(self) -> RenderOptions:
        return self.light.render

    def depth(self, img: torch.Tensor) -> torch.Tensor:
        """``(B, 1, H, W)`` metric depth, predicted at half resolution and upsampled."""
        h, w = img.shape[-2:]
        small = F.avg_pool2d(img, 2, ceil_mode=True)
        x, (sh, sw) = pad_to(_coords(small), self.pts_regressor.multiple)
        logits = self.pts_regressor(x)[..., :sh, :sw]
        logits = F.interpolate(logits, size=(h, w), mode="bilinear", align_corners=False)
        return depth_from_logits(logits, self.options)

    def features(self, img: torch.Tensor) -> torch.Tensor:
        return torch.cat([img, self.encoder(img)], 1)

    def refine(self, s: Splat) -> torch.Tensor:
        colour = s.features[:, :3] / s.coverage.clamp_min(1e-4)
        x, (h, w) = pad_to(torch.cat([s.features, s.coverage], 1), self.projector.multiple)
        return colour + self.projector(x)[..., :h, :w]


def parameters(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())


__all__ = ["LightOptions", "RenderOptions", "SynSinLight", "move_points", "normalise", "parameters", "render", "to_uint8"]
