"""Train the light MiDaS network on RGB-D views of procedural homes, calibrate it, and export it.

    python -m ssga_synthesizer_midas_warp.train --out runs/midas-light \\
        --export plugins/synthesizers/ssga-synthesizer-midas-warp/src/ssga_synthesizer_midas_warp/weights

Steps (resumable: run the same command again after an interruption and it goes on
from the last checkpoint in ``--out``):

1. **Views.** ``views_per_home`` RGB-D views (256 x 256, hfov 90) of every training
   home (procedural seeds ``train_seeds``, 2000-2011; the benchmark evaluates 0, 1, 2),
   cached in ``--out`` (:mod:`.homes`).
2. **Training from scratch** (seeded initialisation, :func:`~.model.init_weights`; no
   pretrained weights) with MiDaS's scale-and-shift-invariant loss on inverse depth
   (Ranftl et al. 2020, ``L_ssitrim + 0.5 L_reg``, :func:`ssi_loss`): per image,
   prediction and truth are shifted by their median and scaled by their mean absolute
   deviation; the loss is the trimmed mean absolute residual (the largest 20% left
   out) plus half the gradient-matching term of the residual at 4 scales; and a hinge
   ``mean(relu(-output))`` on the output before the head's final ReLU, which the
   shift-invariant loss leaves free to drift below zero (clipped pixels would lose
   their depth and their gradient; starting from pretrained weights, MiDaS never meets
   this). Adam with gradients clipped to norm 1 and a cosine learning rate per
   stage; the stages run at growing sizes (most steps at 128 x 128, where a step
   costs ~1/4 of 256 x 256, then 256 x 256, the size the network runs at); random
   horizontal flips and photometric jitter.
3. **Calibration** (:mod:`.calibrate`) on homes 2100-2103.
4. **Held-out figures** (:mod:`.evaluate`) on homes 2200-2203 and Middlebury, for the
   seeded initialisation and the result; export of ``midas-light.pt``
   (``{"network", "state_dict", "provenance"}``), ``midas-light.json`` (the provenance
   and the file's SHA-256) and ``midas-light.calibration.json``.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ssga_bench import TrainingRun, atomic_write_bytes, checkpoint_bytes, cosine_lr, photometric_jitter, training_main
from ssga_bench import training_log as log
from ssga_synthesizer_midas_warp.calibrate import calibrate
from ssga_synthesizer_midas_warp.calibration import calibration_path, sha256_file
from ssga_synthesizer_midas_warp.evaluate import evaluate_network
from ssga_synthesizer_midas_warp.homes import CALIBRATION_SEEDS, HELDOUT_SEEDS, TRAIN_SEEDS, Views, cached_views
from ssga_workspace_procedural.training_homes import bench_and_demo_sized
from ssga_synthesizer_midas_warp.model import LIGHT, MEAN, STD, MidasNet, init_weights

MODULE = "ssga_synthesizer_midas_warp.train"
EXPORT_NAME = "midas-light"


@dataclass(frozen=True)
class TrainConfig:
    """Everything a run depends on (stored in ``--out`` and in the exported weights)."""

    train_seeds: tuple[int, ...] = TRAIN_SEEDS
    views_per_home: int = 250
    stages: tuple[tuple[int, int, int], ...] = ((128, 2000, 16), (256, 300, 8))
    """(image size, optimiser steps, batch size) of each stage."""
    lr: tuple[float, ...] = (1e-3, 3e-4)
    """Adam's peak learning rate in each stage (cosine decay to a tenth of it)."""
    alpha: float = 0.5
    """Weight of the gradient-matching term (MiDaS's)."""
    trim: float = 0.2
    """Share of each image's largest residuals left out of the loss (MiDaS's ssitrim)."""
    scales: int = 4
    """Scales of the gradient-matching term (MiDaS's)."""
    positive: float = 1.0
    """Weight of the hinge that keeps the output positive before MiDaS's final ReLU (the loss cannot see a shift, so it costs the loss nothing)."""
    grad_clip: float = 1.0
    """Gradients are clipped to this global norm (the decoder has no normalisation)."""
    jitter: float = 0.15
    """Photometric jitter: per image, gain within 1 +- jitter and offset within +- jitter / 2 (of 1), per channel gain within +- jitter / 3."""
    calibration_seeds: tuple[int, ...] = CALIBRATION_SEEDS
    calibration_views: int = 50
    heldout_seeds: tuple[int, ...] = HELDOUT_SEEDS
    heldout_views: int = 50
    checkpoint_every: int = 50
    seed: int = 0


# ---------------------------------------------------------------------- the loss


def normalise(d: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per image, ``(d - median(d)) / mean(|d - median(d)|)`` over ``mask`` (MiDaS's scale and shift estimators; sign-preserving)."""
    masked = torch.where(mask, d, torch.full_like(d, float("nan"))).flatten(1)
    median = masked.nanmedian(dim=1).values
    scale = (masked - median[:, None]).abs().nanmean(dim=1).clamp_min(1e-6)
    return (d - median[:, None, None]) / scale[:, None, None]


def ssi_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, alpha: float = 0.5, scales: int = 4, trim: float = 0.2) -> torch.Tensor:
    """MiDaS's ``L_ssitrim + alpha L_reg`` (Ranftl et al. 2020, eqs. 5-11) on inverse depth, batch-based reduction.

    Prediction and target are each shifted by their median and scaled by their mean
    absolute deviation (per image, on ``mask``); the loss is the mean absolute residual
    over each image's ``1 - trim`` smallest residuals, plus ``alpha`` times the
    gradient-matching term: the absolute x and y differences of the residual at
    ``scales`` scales (every ``2 ** k``-th pixel). Unlike a least-squares alignment,
    these estimators keep the sign: the network learns inverse depth (near is high),
    as MiDaS's output is, never depth.
    """
    m = mask.to(pred.dtype)
    res = (normalise(pred, mask) - normalise(target, mask)) * m
    absolute = torch.where(mask, res.abs(), torch.full_like(res, float("inf"))).flatten(1).sort(dim=1).values
    count = mask.flatten(1).sum(dim=1)
    keep = torch.arange(absolute.shape[1], device=pred.device)[None, :] < ((1.0 - trim) * count).floor()[:, None]
    loss = torch.where(keep, absolute, torch.zeros_like(absolute)).sum() / (2 * m.sum()).clamp_min(1)
    if alpha > 0:
        for k in range(scales):
            step = 2**k
            r, mk = res[:, ::step, ::step], m[:, ::step, ::step]
            gx = (r[:, :, 1:] - r[:, :, :-1]).abs() * mk[:, :, 1:] * mk[:, :, :-1]
            gy = (r[:, 1:, :] - r[:, :-1, :]).abs() * mk[:, 1:, :] * mk[:, :-1, :]
            loss = loss + alpha * (gx.sum() + gy.sum()) / mk.sum().clamp_min(1)
    return loss


# ---------------------------------------------------------------------- the run


class Run(TrainingRun):
    """One training run in ``out``: its caches, checkpoints and timings."""

    config: TrainConfig
    module = MODULE
    export_name = EXPORT_NAME
    what = (
        "light MiDaS-small (MidasNet_small layout: EfficientNet-Lite stem 16, stage widths 8/16/24/48/64/96/128, "
        "features 16) trained from scratch on procedural homes with MiDaS's scale-and-shift-invariant loss"
    )
    metrics = ("loss", "positive_output")

    def views(self, seeds: Sequence[int], per_home: int, phase: str) -> Views:
        return self.cached(phase, lambda folder: cached_views(folder, seeds, per_home, progress=log))

    def training_data(self) -> Views:
        return self.views(self.config.train_seeds, self.config.views_per_home, "render")

    def initial(self, data: Views) -> MidasNet:
        net = init_weights(MidasNet(LIGHT), self.config.seed)
        path = self.out / "init.pt"
        if not path.is_file():
            atomic_write_bytes(path, checkpoint_bytes({"state_dict": net.state_dict()}))
        return net

    def network(self) -> MidasNet:
        return MidasNet(LIGHT)

    def begin_stage(self, stage: int, data: Views) -> tuple[np.ndarray, np.ndarray]:
        inverse = np.where(data.depth > 0, 1.0 / np.maximum(data.depth, 1e-6), 0.0).astype(np.float32)
        return _resized(data.rgb, inverse, self.config.stages[stage][0])

    def learning_rate(self, stage: int, step: int, steps: int) -> float:
        return cosine_lr(self.config.lr[stage], step, steps)

    def train_step(self, net, optimizer, stage, data, rng) -> tuple[float, float]:
        """One step; returns the loss and the share of output pixels above zero (the hinge's aim)."""
        c = self.config
        images, targets = data
        idx = rng.choice(len(images), c.stages[stage][2], replace=False)
        x, y = _batch(images[idx], targets[idx], rng, c.jitter)
        pred = net(x, raw=True)
        loss = ssi_loss(pred, y, y > 0, c.alpha, c.scales, c.trim) + c.positive * F.relu(-pred).mean()
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), c.grad_clip)
        optimizer.step()
        return loss.item(), (pred > 0).float().mean().item()

    # ------------------------------------------------------------------ after training

    def after_training(self, net: MidasNet, data: Views) -> dict[str, Any]:
        """Calibration on homes of their own (:mod:`.calibrate`)."""
        c = self.config
        t = time.perf_counter()
        self.calibration_views = self.views(c.calibration_seeds, c.calibration_views, "render calibration")
        cal = self.calibration_views
        self.calibration = calibrate(net, "light", f"{EXPORT_NAME}.pt", "", cal.rgb, cal.depth, seeds=c.calibration_seeds, command=self.invocation, seed=c.seed)
        log(f"calibration: 1 / z = {self.calibration.scale:.5g} * pred + {self.calibration.shift:.5g} ({self.calibration.provenance['fit']}; {time.perf_counter() - t:.0f} s)")
        return {"calibration": {"scale": self.calibration.scale, "shift": self.calibration.shift, **self.calibration.provenance["fit"]}}

    def heldout_figures(self, init: MidasNet, net: MidasNet) -> dict[str, Any]:
        """Depth errors of the seeded initialisation (calibrated as the result is) and the result on the held-out homes."""
        c, cal = self.config, self.calibration_views
        held = self.views(c.heldout_seeds, c.heldout_views, "render held-out")
        init_cal = calibrate(init, "light", "init.pt", "", cal.rgb, cal.depth, seeds=c.calibration_seeds, seed=c.seed)
        return {"init": evaluate_network(init, init_cal, held.rgb, held.depth), "trained": evaluate_network(net, self.calibration, held.rgb, held.depth)}

    def provenance_extra(self, net: MidasNet) -> dict[str, Any]:
        c = self.config
        return {
            "train_seeds": list(c.train_seeds),
            "calibration_seeds": list(c.calibration_seeds),
            "heldout_seeds": list(c.heldout_seeds),
            "homes": {"even seeds": dict(bench_and_demo_sized(0)), "odd seeds": dict(bench_and_demo_sized(1))},
        }

    def payload(self, net: MidasNet) -> dict[str, Any]:
        return {"network": "light", "state_dict": net.state_dict()}

    def export(self, net: MidasNet, provenance: dict[str, Any], folder: Path) -> Path:
        """The weights, and beside them their calibration, which names the file's SHA-256."""
        path = super().export(net, provenance, folder)
        dataclasses.replace(self.calibration, weights_sha256=sha256_file(path)).write(calibration_path(path))
        return path


def _resized(rgb: np.ndarray, inverse: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Images and inverse depths at ``size`` x ``size`` (area averaging; a pixel with unknown depth stays unknown)."""
    if rgb.shape[1:3] == (size, size):
        return rgb, inverse
    out_rgb = np.empty((len(rgb), size, size, 3), dtype=np.uint8)
    out_inv = np.empty((len(rgb), size, size), dtype=np.float32)
    for i in range(len(rgb)):
        out_rgb[i] = cv2.resize(rgb[i], (size, size), interpolation=cv2.INTER_AREA)
        valid = cv2.resize((inverse[i] > 0).astype(np.float32), (size, size), interpolation=cv2.INTER_AREA)
        out_inv[i] = np.where(valid > 0.999, cv2.resize(inverse[i], (size, size), interpolation=cv2.INTER_AREA), 0.0)
    return out_rgb, out_inv


def _batch(rgb: np.ndarray, inverse: np.ndarray, rng: np.random.Generator, jitter: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised network input and target inverse depth, with random flips and photometric jitter."""
    x = photometric_jitter(rgb.astype(np.float32) / 255.0, rng, jitter)
    x = (x - np.asarray(MEAN, np.float32)) / np.asarray(STD, np.float32)
    y = inverse.copy()
    flip = rng.random(len(rgb)) < 0.5
    x[flip], y[flip] = x[flip, :, ::-1], y[flip, :, ::-1]
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2), dtype=np.float32)), torch.from_numpy(np.ascontiguousarray(y))


run_training = Run.run_training
"""Every step of the module docstring; returns what was exported."""


def main(argv: Sequence[str] | None = None) -> int:
    return training_main(MODULE, __doc__, run_training, TrainConfig(), argv, exports=f"{EXPORT_NAME}.pt, .json and .calibration.json")


if __name__ == "__main__":
    sys.exit(main())
