"""Train the light SynSin network on view pairs of procedural homes.

    python -m ssga_synthesizer_synsin.train --out runs/synsin-light \\
        --export plugins/synthesizers/ssga-synthesizer-synsin/src/ssga_synthesizer_synsin/weights

Steps (resumable: run the same command again after an interruption and it goes on
from the last checkpoint in ``--out``):

1. **Pairs.** ``pairs_per_home`` orbit pairs (:mod:`.pairs`) in each training home
   (procedural seeds ``train_seeds``, 3000-3005; the benchmark uses 0, 1, 2), RGB and
   true depth, cached in ``--out``.
2. **Training**, end to end through the splatter, as SynSin trains: each sample is a
   pair in either direction, mirrored left-right half the time (the move mirrored with
   it); the loss is ``L1 + ssim_weight * (1 - SSIM) / 2`` of the rendered target against
   the true one, plus ``depth_weight`` times the L1 error of the log depth the network
   predicts for both views against the true depth (SynSin's ``--train_depth`` with the
   true depth of the renders; SynSin's perceptual and adversarial losses are left out:
   a VGG19 pass per step costs more than the whole light network). Adam. The stages run
   at growing image sizes: most steps at 128 x 128 (the depth network always sees the
   256 x 256 view, the size it runs at, and its depth is pooled to 128), then 256 x 256.
3. **Held-out figures** (:mod:`.evaluate`) of the initialisation and the result, and
   the export: ``synsin-light.pt`` (``{"state_dict", "opts", "provenance"}``) and
   ``synsin-light.json`` (the provenance and the file's SHA-256).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ssga_bench import TrainingRun, atomic_write_bytes, cached_homes, checkpoint_bytes, training_main
from ssga_bench import training_log as log
from ssga_synthesizer_synsin.evaluate import HeldOut, evaluate, render_heldout
from ssga_synthesizer_synsin.model import LightOptions, SynSinLight, parameters, render
from ssga_synthesizer_synsin.pairs import TRAIN_SEEDS, Pairs, render_pairs
from ssga_workspace_procedural.training_homes import RENDERER_VERSION

MODULE = "ssga_synthesizer_synsin.train"
EXPORT_NAME = "synsin-light"


@dataclass(frozen=True)
class TrainConfig:
    """Everything a run depends on (stored in ``--out`` and in the exported weights)."""

    train_seeds: tuple[int, ...] = TRAIN_SEEDS
    pairs_per_home: int = 200
    distance_m: tuple[float, float] = (0.6, 1.4)
    max_turn_deg: float = 60.0
    stages: tuple[tuple[int, int, int], ...] = ((128, 250, 8), (256, 60, 2))
    """(image size, optimiser steps, batch size) of each stage."""
    lr: tuple[float, ...] = (1e-3, 3e-4)
    ssim_weight: float = 1.0
    depth_weight: float = 1.0
    heldout: HeldOut = field(default_factory=HeldOut)
    checkpoint_every: int = 25
    seed: int = 0


class Run(TrainingRun):
    """One training run in ``out``: its caches, checkpoints and timings."""

    config: TrainConfig
    module = MODULE
    export_name = EXPORT_NAME

    def training_data(self) -> Pairs:
        c = self.config
        settings = {"pairs_per_home": c.pairs_per_home, "distance_m": list(c.distance_m), "max_turn_deg": c.max_turn_deg, "renderer": RENDERER_VERSION}

        def render(seed: int) -> Pairs:
            return render_pairs(seed, c.pairs_per_home, distance_m=c.distance_m, max_turn_deg=c.max_turn_deg)

        return self.cached("render", lambda folder: cached_homes(folder, "pairs", c.train_seeds, settings, render, Pairs, progress=log))

    def initial(self, data: Pairs) -> SynSinLight:
        torch.manual_seed(self.config.seed)
        return SynSinLight(LightOptions())

    def network(self) -> SynSinLight:
        return SynSinLight(LightOptions())

    def training_input(self, data: Pairs) -> tuple[Pairs, np.ndarray]:
        return data, _moves(data)  # the pairs and their moves

    def heldout_figures(self, init: SynSinLight, net: SynSinLight) -> dict[str, Any]:
        """Synthesis and depth figures of the initialisation and the result, each through the plugin as a user runs it."""
        from ssga_synthesizer_synsin.plugin import SynSinConfig, SynSinSynthesizer

        heldout = render_heldout(self.config.heldout)
        figures = {}
        for name, model in (("init", init), ("trained", net)):
            path = self.out / f"{name}-eval.pt"
            atomic_write_bytes(path, checkpoint_bytes({"state_dict": model.state_dict(), "opts": model.light.to_json()}))
            synthesizer = SynSinSynthesizer(SynSinConfig(weights=str(path.resolve()), device="cpu"))
            figures[name] = evaluate(synthesizer, heldout, references=name == "trained")
        return figures

    def describe(self, net: SynSinLight) -> str:
        return (
            f"light SynSin ({parameters(net) / 1e6:.2f} M parameters: half-resolution depth U-Net, feature encoder, "
            "refinement U-Net) trained on procedural homes"
        )

    def provenance_extra(self, net: SynSinLight) -> dict[str, Any]:
        return {"train_seeds": list(self.config.train_seeds), "heldout_seeds": list(self.config.heldout.seeds), "opts": net.light.to_json()}

    def payload(self, net: SynSinLight) -> dict[str, Any]:
        return {"state_dict": net.state_dict(), "opts": net.light.to_json()}

    metrics = ("loss", "l1", "ssim", "log_depth_l1")
    unit = "pairs"

    def train_step(self, net, optimizer, stage, data, rng) -> list[float]:
        pairs, moves = data
        size, _, batch = self.config.stages[stage]
        return _step(net, optimizer, pairs, moves, size, batch, self.config, rng)


def _moves(data: Pairs) -> np.ndarray:
    """``(N, 2, 4, 4)``: for each pair, ``T_target<-source`` and the reverse."""
    out = np.empty((len(data), 2, 4, 4), dtype=np.float32)
    for i in range(len(data)):
        a, b = data.pose(i, 0), data.pose(i, 1)
        out[i, 0] = b.relative_to(a)
        out[i, 1] = a.relative_to(b)
    return out


MIRROR = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0]))
"""Mirroring images left-right mirrors the camera frame's x: ``T' = M T M``."""


def intrinsics(size: int, full: int = 256) -> torch.Tensor:
    """The benchmark camera's K (hfov 90) at ``size`` x ``size`` pixels (area-pooled from ``full``)."""
    f = (size / 2.0) / np.tan(np.radians(45.0))
    c = (size - 1) / 2.0
    return torch.tensor([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]], dtype=torch.float32)


def batch_tensors(data: Pairs, moves: np.ndarray, rng: np.random.Generator, batch: int) -> dict[str, torch.Tensor]:
    """A random batch at full size: source and target images in [-1, 1], true depths, moves (mirrored at random)."""
    idx = rng.integers(0, len(data), batch)
    direction = rng.integers(0, 2, batch)
    mirror = rng.random(batch) < 0.5
    rgb = torch.from_numpy(data.rgb[idx]).permute(0, 1, 4, 2, 3).float().div(127.5).sub(1.0)  # (B, 2, 3, H, W)
    depth = torch.from_numpy(data.depth[idx].astype(np.float32))  # (B, 2, H, W)
    src_k = torch.from_numpy(direction)
    ar = torch.arange(batch)
    source, target = rgb[ar, src_k], rgb[ar, 1 - src_k]
    source_depth, target_depth = depth[ar, src_k], depth[ar, 1 - src_k]
    T = torch.from_numpy(moves[idx, direction])
    flip = torch.from_numpy(mirror)
    source = torch.where(flip[:, None, None, None], source.flip(-1), source)
    target = torch.where(flip[:, None, None, None], target.flip(-1), target)
    source_depth = torch.where(flip[:, None, None], source_depth.flip(-1), source_depth)
    target_depth = torch.where(flip[:, None, None], target_depth.flip(-1), target_depth)
    T = torch.where(flip[:, None, None], MIRROR @ T @ MIRROR, T)
    return {
        "source": source,
        "target": target,
        "source_depth": source_depth[:, None],
        "target_depth": target_depth[:, None],
        "T": T,
    }


def ssim(a: torch.Tensor, b: torch.Tensor, sigma: float = 1.5, size: int = 11) -> torch.Tensor:
    """Mean SSIM of images in [-1, 1] (data range 2), Gaussian window, per channel."""
    x = torch.arange(size, dtype=a.dtype) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = (g / g.sum()).to(a.device)
    c = a.shape[1]
    kx = g.view(1, 1, 1, size).expand(c, 1, 1, size)
    ky = g.view(1, 1, size, 1).expand(c, 1, size, 1)

    def blur(t: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(t, kx, groups=c), ky, groups=c)

    c1, c2 = (0.01 * 2) ** 2, (0.03 * 2) ** 2
    mu_a, mu_b = blur(a), blur(b)
    var_a, var_b, cov = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2, blur(a * b) - mu_a * mu_b
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return s.mean()


def _log_depth_l1(pred: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    known = true > 0
    return (pred[known].log() - true[known].log()).abs().mean() if known.any() else pred.sum() * 0.0


def _step(net: SynSinLight, optimizer, data: Pairs, moves: np.ndarray, size: int, batch: int, c: TrainConfig, rng) -> list[float]:
    """One optimiser step; returns ``[loss, L1, SSIM, log-depth L1]``."""
    b = batch_tensors(data, moves, rng, batch)
    full = b["source"].shape[-1]
    depth = net.depth(b["source"])  # the depth network at the size it runs at
    depth_loss = _log_depth_l1(depth, b["source_depth"])
    source, target = b["source"], b["target"]
    if size != full:
        factor = full // size
        source, target = F.avg_pool2d(source, factor), F.avg_pool2d(target, factor)
        depth = F.avg_pool2d(depth, factor)
    out, _, _ = render(net, source, intrinsics(size, full), b["T"], depth=depth)
    l1 = (out - target).abs().mean()
    s = ssim(out, target)
    loss = l1 + c.ssim_weight * (1 - s) / 2 + c.depth_weight * depth_loss
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    return [loss.item(), l1.item(), s.item(), depth_loss.item()]


def main(argv: Sequence[str] | None = None) -> int:
    return training_main(MODULE, __doc__, run_training, TrainConfig(), argv, exports=f"{EXPORT_NAME}.pt and {EXPORT_NAME}.json")


run_training = Run.run_training
"""Every step of the module docstring; returns what was exported."""


if __name__ == "__main__":
    sys.exit(main())
