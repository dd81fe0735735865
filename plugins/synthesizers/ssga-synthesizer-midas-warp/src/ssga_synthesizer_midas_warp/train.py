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

import argparse
import dataclasses
import datetime
import hashlib
import json
import math
import platform
import shlex
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

from ssga_core import InputError
from ssga_bench import TrainingRun, atomic_write_bytes, checkpoint_bytes, load_checkpoint, write_json
from ssga_bench import training_log as log
from ssga_synthesizer_midas_warp.calibrate import calibrate
from ssga_synthesizer_midas_warp.calibration import calibration_path, sha256_file
from ssga_synthesizer_midas_warp.evaluate import evaluate_network
from ssga_synthesizer_midas_warp.homes import CALIBRATION_SEEDS, HELDOUT_SEEDS, TRAIN_SEEDS, Views, cached_views, home_settings
from ssga_synthesizer_midas_warp.model import LIGHT, MEAN, STD, MidasNet, init_weights

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

    def to_json(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self)))


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

    def views(self, seeds: Sequence[int], per_home: int, phase: str) -> Views:
        t = time.perf_counter()
        views = cached_views(self.out / "views", seeds, per_home, progress=log)
        self.timed(phase, time.perf_counter() - t)
        return views

    def initial(self) -> MidasNet:
        net = init_weights(MidasNet(LIGHT), self.config.seed)
        path = self.out / "init.pt"
        if not path.is_file():
            atomic_write_bytes(path, checkpoint_bytes({"state_dict": net.state_dict()}))
        return net

    def train(self, net: MidasNet, data: Views) -> tuple[MidasNet, list[list[float]]]:
        c = self.config
        state_path = self.out / "state.pt"
        optimizer = torch.optim.Adam(net.parameters(), lr=c.lr[0])
        stage, step, history = 0, 0, []
        if state_path.is_file():
            state = load_checkpoint(state_path, "training state")
            net.load_state_dict(state["state_dict"])
            optimizer.load_state_dict(state["optimizer"])
            stage, step, history = int(state["stage"]), int(state["step"]), [list(h) for h in state["history"]]
            log(f"resuming at stage {stage + 1}, step {step}")
        inverse = np.where(data.depth > 0, 1.0 / np.maximum(data.depth, 1e-6), 0.0).astype(np.float32)
        while stage < len(c.stages):
            size, steps, batch = c.stages[stage]
            images, targets = (_resized(data.rgb, inverse, size) if step < steps else (None, None))
            t0, window = time.perf_counter(), []
            net.train()
            while step < steps:
                lr = c.lr[stage] * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * step / steps)))
                for g in optimizer.param_groups:
                    g["lr"] = lr
                rng = np.random.default_rng([c.seed, 2, stage, step])
                idx = rng.choice(len(images), batch, replace=False)
                x, y = _batch(images[idx], targets[idx], rng, c.jitter)
                pred = net(x, raw=True)
                loss = ssi_loss(pred, y, y > 0, c.alpha, c.scales, c.trim) + c.positive * F.relu(-pred).mean()
                optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(net.parameters(), c.grad_clip)
                optimizer.step()
                step += 1
                window.append((loss.item(), (pred > 0).float().mean().item()))
                history.append([stage, step, loss.item()])
                if step % c.checkpoint_every == 0 or step == steps:
                    elapsed = time.perf_counter() - t0
                    self.timed(f"stage{stage + 1}", elapsed)
                    t0 = time.perf_counter()
                    self._save_state(net, optimizer, stage, step, history)
                    rate = len(window) * batch / elapsed
                    eta = (steps - step) * batch / rate
                    mean_loss, positive = np.mean(window, axis=0)
                    log(
                        f"stage {stage + 1}/{len(c.stages)} ({size} px) step {step}/{steps}: loss {mean_loss:.4f}, "
                        f"output > 0 at {positive:.0%} of pixels, lr {lr:.2g}, {rate:.1f} images/s, stage ends in {eta / 60:.1f} min"
                    )
                    window = []
            stage, step = stage + 1, 0
            self._save_state(net, optimizer, stage, step, history)
        net.eval()
        return net, history

    def _save_state(self, net, optimizer, stage, step, history) -> None:
        state = {"state_dict": net.state_dict(), "optimizer": optimizer.state_dict(), "stage": stage, "step": step, "history": history}
        atomic_write_bytes(self.out / "state.pt", checkpoint_bytes(state))


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
    n = len(rgb)
    x = rgb.astype(np.float32) / 255.0
    gain = rng.uniform(1 - jitter, 1 + jitter, (n, 1, 1, 1)) * rng.uniform(1 - jitter / 3, 1 + jitter / 3, (n, 1, 1, 3))
    x = np.clip(x * gain + rng.uniform(-jitter / 2, jitter / 2, (n, 1, 1, 1)), 0.0, 1.0)
    x = (x - np.asarray(MEAN, np.float32)) / np.asarray(STD, np.float32)
    y = inverse.copy()
    flip = rng.random(n) < 0.5
    x[flip], y[flip] = x[flip, :, ::-1], y[flip, :, ::-1]
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2), dtype=np.float32)), torch.from_numpy(np.ascontiguousarray(y))


def export(net: MidasNet, provenance: dict[str, Any], folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{EXPORT_NAME}.pt"
    data = checkpoint_bytes({"network": "light", "state_dict": net.state_dict(), "provenance": provenance})
    atomic_write_bytes(path, data)
    write_json(folder / f"{EXPORT_NAME}.json", {**provenance, "file": path.name, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    return path


def run_training(config: TrainConfig, out: Path, export_to: Path, *, evaluate_heldout: bool = True, argv: Sequence[str] | None = None) -> Path:
    """Every step of the module docstring; returns the exported weights' path."""
    run = Run(config, out)
    started = datetime.datetime.now(datetime.timezone.utc)
    command = "python -m ssga_synthesizer_midas_warp.train " + shlex.join(sys.argv[1:] if argv is None else list(argv))
    data = run.views(config.train_seeds, config.views_per_home, "render")
    log(f"{len(data)} training views of {len(config.train_seeds)} homes")
    init = run.initial()
    net = MidasNet(LIGHT)
    net.load_state_dict(init.state_dict())
    net, history = run.train(net, data)
    training_s = sum(run.times.values())
    figures: dict[str, Any] = {"training_seconds": round(training_s, 1), "seconds": {k: round(v, 1) for k, v in run.times.items()}}
    figures["loss"] = _loss_summary(history, config)
    provenance = {
        "what": "light MiDaS-small (MidasNet_small layout: EfficientNet-Lite stem 16, stage widths 8/16/24/48/64/96/128, "
        "features 16) trained from scratch on procedural homes with MiDaS's scale-and-shift-invariant loss",
        "command": command,
        "date": started.isoformat(timespec="seconds"),
        "train_seeds": list(config.train_seeds),
        "calibration_seeds": list(config.calibration_seeds),
        "heldout_seeds": list(config.heldout_seeds),
        "homes": {"even seeds": home_settings(0), "odd seeds": home_settings(1)},
        "config": config.to_json(),
        "figures": figures,
        "torch": str(torch.__version__),
        "python": platform.python_version(),
        "threads": torch.get_num_threads(),
    }
    # Calibration on homes of their own, then held-out figures (of the seeded initialisation too).
    t = time.perf_counter()
    cal_views = cached_views(out / "views", config.calibration_seeds, config.calibration_views, progress=log)
    calibration = calibrate(net, "light", f"{EXPORT_NAME}.pt", "", cal_views.rgb, cal_views.depth, seeds=config.calibration_seeds, command=command, seed=config.seed)
    log(f"calibration: 1 / z = {calibration.scale:.5g} * pred + {calibration.shift:.5g} ({calibration.provenance['fit']}; {time.perf_counter() - t:.0f} s)")
    figures["calibration"] = {"scale": calibration.scale, "shift": calibration.shift, **calibration.provenance["fit"]}
    if evaluate_heldout:
        t = time.perf_counter()
        held = cached_views(out / "views", config.heldout_seeds, config.heldout_views, progress=log)
        init_cal = calibrate(init, "light", "init.pt", "", cal_views.rgb, cal_views.depth, seeds=config.calibration_seeds, seed=config.seed)
        figures["heldout"] = {
            "init": evaluate_network(init.eval(), init_cal, held.rgb, held.depth),
            "trained": evaluate_network(net, calibration, held.rgb, held.depth),
        }
        figures["heldout_seconds"] = round(time.perf_counter() - t, 1)
        log(f"held-out figures: {json.dumps(figures['heldout']['trained'])}")
    path = export(net, provenance, export_to)
    dataclasses.replace(calibration, weights_sha256=sha256_file(path)).write(calibration_path(path))
    log(f"exported {path} ({path.stat().st_size / 1e6:.1f} MB); training took {training_s / 60:.1f} min")
    return path


def _loss_summary(history: list[list[float]], config: TrainConfig) -> list[dict[str, Any]]:
    out = []
    for stage, (size, steps, batch) in enumerate(config.stages):
        rows = np.array([h for h in history if int(h[0]) == stage]).reshape(-1, 3)
        if len(rows):
            w = max(1, min(50, len(rows) // 4))
            out.append({"size": size, "steps": steps, "batch": batch, "loss_first": round(float(rows[:w, 2].mean()), 5), "loss_last": round(float(rows[-w:, 2].mean()), 5), "window": w})
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ssga_synthesizer_midas_warp.train", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="run folder: view caches, checkpoints (resumable), results")
    parser.add_argument("--export", type=Path, default=None, help="folder for midas-light.pt, .json and .calibration.json (default: --out)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--no-eval", action="store_true", help="skip the held-out figures")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        run_training(TrainConfig(), args.out, args.export or args.out, evaluate_heldout=not args.no_eval, argv=argv)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
