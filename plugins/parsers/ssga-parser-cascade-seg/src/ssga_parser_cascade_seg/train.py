"""Train the light scene-parsing network on labelled views of procedural homes, and export it.

    python -m ssga_parser_cascade_seg.train --out runs/cascade-seg-light-balanced \\
        --export plugins/parsers/ssga-parser-cascade-seg/src/ssga_parser_cascade_seg/weights/procedural-light-ppm_deepsup

Steps (resumable: run the same command again after an interruption and it goes on
from the last checkpoint in ``--out``):

1. **Views.** ``views_per_home`` views (256 x 256, hfov 90) of every training home
   (procedural seeds ``train_seeds``, 4000-4011; the benchmark evaluates 0, 1, 2) with
   their ground-truth semantic ids as class labels (:mod:`.homes`), cached in ``--out``.
2. **Training from scratch** (CSAIL's initialisation, seeded; no pretrained weights) of
   the :data:`~.model.LIGHT` layout, as CSAIL trains: cross-entropy of the main head
   plus ``deep_sup_scale`` (0.4) times that of the deep-supervision head on ``layer3``,
   unknown pixels ignored, learning rate decayed as ``(1 - step / steps) ** 0.9``. Here
   the logits are upsampled to the labels' size (CSAIL downsamples the labels to the
   logits' instead), Adam replaces SGD (no pretrained encoder to keep), and each class
   weighs its pixel frequency to the power -0.5 (``class_balance``; walls, floors and
   ceilings cover 90 % of the pixels). Stage 1 runs at 128 x 128 crops of the views
   rescaled by a random factor in ``scale_range`` (0.5: the whole view; 1: its native
   scale), where a step costs about a quarter of one at 256 x 256; stage 2 at the
   views' own 256 x 256, the size the parser runs at. Random horizontal flips and
   photometric jitter throughout.
3. **Held-out figures** (:mod:`.evaluate`) on homes 4100-4103, for the seeded
   initialisation and the result, single-scale (256) and multi-scale; export of
   ``encoder_epoch_20.pth`` and ``decoder_epoch_20.pth`` (each ``{"network",
   "classes", "state_dict", "provenance"}``, the release's file names) and
   ``provenance.json`` (with the files' SHA-256) into ``--export``.
"""

from __future__ import annotations

import hashlib
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ssga_core import InputError
from ssga_bench import TrainingRun, atomic_write_bytes, checkpoint_bytes, photometric_jitter, poly_lr, training_main, write_json
from ssga_bench import training_log as log
from ssga_parser_cascade_seg.classes import PROCEDURAL
from ssga_parser_cascade_seg.evaluate import evaluate
from ssga_parser_cascade_seg.homes import HELDOUT_SEEDS, TRAIN_SEEDS, Labelled, cached_labelled
from ssga_parser_cascade_seg.model import LIGHT, MEAN, STD, SceneParser, init_weights, predict
from ssga_parser_cascade_seg.plugin import FILES, LIGHT_SCALES

MODULE = "ssga_parser_cascade_seg.train"


@dataclass(frozen=True)
class TrainConfig:
    """Everything a run depends on (stored in ``--out`` and in the exported weights)."""

    train_seeds: tuple[int, ...] = TRAIN_SEEDS
    views_per_home: int = 160
    stages: tuple[tuple[int, int, int], ...] = ((128, 1200, 16), (256, 250, 8))
    """(crop size, optimiser steps, batch size) of each stage."""
    lr: tuple[float, ...] = (2e-3, 5e-4)
    """Adam's initial learning rate in each stage, decayed by CSAIL's poly rule (power 0.9)."""
    weight_decay: float = 1e-4
    deep_sup_scale: float = 0.4
    class_balance: float = 0.5
    """Each class's pixels weigh its training frequency to the power ``-class_balance`` in the
    cross-entropy (scaled so the average pixel weighs 1); 0: unweighted, as CSAIL trains. Walls,
    floors and ceilings cover 90 % of the pixels: unweighted, the light network never predicted a
    lamp on held-out homes (IoU 0.00, mIoU 0.517; see the README)."""
    scale_range: tuple[float, float] = (0.5, 1.0)
    """Stage 1's random rescaling of the views before cropping (later stages run at 1)."""
    jitter: float = 0.15
    """Photometric jitter: per image, gain within 1 +- jitter and offset within +- jitter / 2 (of 1), per channel gain within +- jitter / 3."""
    heldout_seeds: tuple[int, ...] = HELDOUT_SEEDS
    heldout_views: int = 50
    checkpoint_every: int = 50
    seed: int = 0


class Run(TrainingRun):
    """One training run in ``out``: its view caches, checkpoints and timings."""

    config: TrainConfig
    module = MODULE
    what = (
        "light CSAIL scene-parsing network (deep-stem ResNet18-dilated at widths stem 16/16/32, stages 16/32/64/128, "
        "PPM-deepsup at 64; output stride 8) trained from scratch on ground-truth semantic labels of procedural homes"
    )
    metrics = ("loss", "pixel_accuracy")
    rng_stream = 3

    def views(self, seeds: Sequence[int], per_home: int, phase: str) -> Labelled:
        return self.cached(phase, lambda folder: cached_labelled(folder, seeds, per_home, progress=log))

    def training_data(self) -> Labelled:
        _check_vocabulary()
        return self.views(self.config.train_seeds, self.config.views_per_home, "render")

    def initial(self, data: Labelled) -> SceneParser:
        return init_weights(SceneParser(LIGHT, len(PROCEDURAL)), self.config.seed)

    def network(self) -> SceneParser:
        return SceneParser(LIGHT, len(PROCEDURAL))

    def optimizer(self, net: SceneParser) -> torch.optim.Optimizer:
        return torch.optim.AdamW(net.parameters(), lr=self.config.lr[0], weight_decay=self.config.weight_decay)

    def training_input(self, data: Labelled) -> tuple[Labelled, torch.Tensor]:
        """The views and the class weights of the cross-entropy (from the views' pixel counts)."""
        self.pixels = class_pixels(data.labels, len(PROCEDURAL))
        self.weight = class_weights(self.pixels, self.config.class_balance)
        return data, self.weight

    def learning_rate(self, stage: int, step: int, steps: int) -> float:
        return poly_lr(self.config.lr[stage], step, steps)

    def train_step(self, net, optimizer, stage, data, rng) -> tuple[float, float]:
        c = self.config
        views, weight = data
        size, _, batch = c.stages[stage]
        x, y = _batch(views, rng, batch, size, c.scale_range if stage == 0 else (1.0, 1.0), c.jitter)
        return _step(net, optimizer, x, y, c.deep_sup_scale, weight)

    def after_training(self, net: SceneParser, data: Labelled) -> dict[str, Any]:
        return {
            "train_pixels": {name: int(n) for name, n in zip(PROCEDURAL, self.pixels, strict=True)},
            "class_weights": {name: round(float(w), 3) for name, w in zip(PROCEDURAL, self.weight, strict=True)},
        }

    def heldout_figures(self, init: SceneParser, net: SceneParser) -> dict[str, Any]:
        """mIoU and pixel accuracy of the initialisation (single-scale) and the result (single- and multi-scale)."""
        held = self.views(self.config.heldout_seeds, self.config.heldout_views, "render held-out")
        figures = {}
        for name, scales_name, model, scales in (
            ("init", "single-scale", init, (256,)),
            ("trained", "single-scale", net, (256,)),
            ("trained", "multi-scale", net, LIGHT_SCALES),
        ):
            figures[f"{name} {scales_name}"] = evaluate(lambda rgb, m=model, s=scales: predict(m, rgb, s).argmax(0).numpy(), held, PROCEDURAL)
        return figures

    def provenance_extra(self, net: SceneParser) -> dict[str, Any]:
        c = self.config
        return {"network": "light", "classes": list(PROCEDURAL), "train_seeds": list(c.train_seeds), "heldout_seeds": list(c.heldout_seeds)}

    def export(self, net: SceneParser, provenance: dict[str, Any], folder: Path) -> Path:
        """The two release files (with ``provenance``) and ``provenance.json`` into ``folder``; returns ``folder``."""
        folder.mkdir(parents=True, exist_ok=True)
        files = {}
        for name, part in ((FILES["encoder"], net.encoder), (FILES["decoder"], net.decoder)):
            data = checkpoint_bytes({"network": "light", "classes": "procedural", "state_dict": part.state_dict(), "provenance": provenance})
            atomic_write_bytes(folder / name, data)
            files[name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
        write_json(folder / "provenance.json", {**provenance, "files": files})
        return folder


def class_pixels(labels: np.ndarray, num_class: int) -> np.ndarray:
    """Labelled pixels of each class in ``(N, H, W)`` class maps (``-1`` unknown), counted view by view."""
    counts = np.zeros(num_class, dtype=np.int64)
    for view in labels:
        counts += np.bincount(view[view >= 0].astype(np.intp), minlength=num_class)[:num_class]
    return counts


def class_weights(counts: np.ndarray, balance: float) -> torch.Tensor:
    """Cross-entropy weights ``frequency ** -balance``, scaled so the average training pixel weighs 1 (absent classes: 0)."""
    freq = counts / max(int(counts.sum()), 1)
    w = np.where(counts > 0, np.maximum(freq, 1e-12) ** -balance, 0.0)
    return torch.tensor(w / max(float((freq * w).sum()), 1e-12), dtype=torch.float32)


def _step(net: SceneParser, optimizer: torch.optim.Optimizer, x: torch.Tensor, y: torch.Tensor, deep_sup_scale: float, weight: torch.Tensor | None = None) -> tuple[float, float]:
    """One optimiser step; returns the loss and the main head's pixel accuracy on the batch."""
    logits, deepsup = net.forward_train(x)
    size = y.shape[1:]
    logits = F.interpolate(logits, size, mode="bilinear", align_corners=False)
    deepsup = F.interpolate(deepsup, size, mode="bilinear", align_corners=False)
    loss = F.cross_entropy(logits, y, weight, ignore_index=-1) + deep_sup_scale * F.cross_entropy(deepsup, y, weight, ignore_index=-1)
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    known = y >= 0
    accuracy = (logits.argmax(1)[known] == y[known]).float().mean().item() if known.any() else 0.0
    return loss.item(), accuracy


def _batch(data: Labelled, rng: np.random.Generator, batch: int, size: int, scales: tuple[float, float], jitter: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``batch`` random views, rescaled by one random factor, cropped to ``size`` (padded with unknown if smaller), flipped and jittered."""
    idx = rng.choice(len(data), batch, replace=False)
    scale = rng.uniform(*scales)
    # Zeros, not empty: padding is labelled unknown, but its pixels still pass through the convolutions, and
    # uninitialised memory can hold NaN that spreads into the loss (only views smaller than the crop are padded).
    images = np.zeros((batch, size, size, 3), dtype=np.float32)
    labels = np.full((batch, size, size), -1, dtype=np.int64)
    for i, k in enumerate(idx):
        rgb, lab = data.rgb[k], data.labels[k]
        h, w = lab.shape
        sh, sw = max(1, round(h * scale)), max(1, round(w * scale))
        if (sh, sw) != (h, w):
            rgb = cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA)
            # Nearest label of each new pixel's centre (class indices must not be averaged).
            rows = np.minimum(((np.arange(sh) + 0.5) * h / sh).astype(np.intp), h - 1)
            cols = np.minimum(((np.arange(sw) + 0.5) * w / sw).astype(np.intp), w - 1)
            lab = lab[rows[:, None], cols[None, :]]
        top, left = rng.integers(0, max(sh - size, 0) + 1), rng.integers(0, max(sw - size, 0) + 1)
        rgb, lab = rgb[top : top + size, left : left + size], lab[top : top + size, left : left + size]
        if rng.random() < 0.5:
            rgb, lab = rgb[:, ::-1], lab[:, ::-1]
        images[i, : rgb.shape[0], : rgb.shape[1]] = rgb / 255.0
        labels[i, : lab.shape[0], : lab.shape[1]] = lab
    images = photometric_jitter(images, rng, jitter)
    images = (images - np.asarray(MEAN, np.float32)) / np.asarray(STD, np.float32)
    return torch.from_numpy(np.ascontiguousarray(images.transpose(0, 3, 1, 2), dtype=np.float32)), torch.from_numpy(labels)


run_training = Run.run_training
"""Every step of the module docstring; returns what was exported."""


def _check_vocabulary() -> None:
    """The class names the weights will carry are the procedural categories, in id order from 1."""
    from ssga_workspace_procedural.categories import CATEGORIES

    by_id = sorted(CATEGORIES, key=CATEGORIES.__getitem__)
    if tuple(by_id) != PROCEDURAL or [CATEGORIES[n] for n in by_id] != list(range(1, len(by_id) + 1)):
        raise InputError(f"the procedural categories {CATEGORIES} are not classes.PROCEDURAL with ids 1..{len(PROCEDURAL)}; update classes.py")


def main(argv: Sequence[str] | None = None) -> int:
    return training_main(
        MODULE, __doc__, run_training, TrainConfig(), argv,
        exports="encoder_epoch_20.pth, decoder_epoch_20.pth and provenance.json", default_export=lambda out: out / "weights",
    )


if __name__ == "__main__":
    sys.exit(main())
