"""Train the light Patch-NetVLAD network on procedural homes, as NetVLAD trains from GPS.

    python -m ssga_descriptor_pnv.train --out runs/pnv-light \\
        --export plugins/descriptors/ssga-descriptor-pnv/src/ssga_descriptor_pnv/weights

Steps (each resumable: run the same command again after an interruption and it goes
on from the last checkpoint in ``--out``):

1. **Views.** ``places_per_home`` places of two views each in every training home
   (procedural seeds ``train_seeds``, 1000-1007; the benchmark uses 0, 1, 2), cached
   in ``--out``. Positives and negatives come from the poses (:mod:`.homes`).
2. **Initialisation.** VGG-style Kaiming weights (seeded); NetVLAD's centroids by
   k-means on L2-normalised conv5_3 descriptors of training views, and its
   assignment conv from them, as the reference's ``get_clusters`` / ``init_params``.
3. **Triplet training** of the whole network on the global NetVLAD descriptor:
   each batch holds two views of ``places_per_batch`` places from ``homes_per_batch``
   homes; each view is an anchor, its place's other view the positive, and its
   ``hard_negatives`` nearest negatives in the batch the negatives; loss
   ``max(0, d(a, p) - d(a, n) + sqrt(margin))`` with PNV's margin 0.1 (as its
   ``TripletMarginLoss(margin ** 0.5)``), averaged over triplets; Adam. The stages
   run at growing image sizes (most steps at 128 x 128, where a step costs ~1/8 of
   256 x 256; then 256 x 256, the size the descriptor runs at).
4. **WPCA**: PCA whitening of ``pca_images`` training views' global descriptors at
   256 x 256 into ``num_pcs`` dimensions, as the reference's ``add_pca.py``.
5. **Held-out figures** (:mod:`.evaluate`) of the initialisation and the result, and
   the export: ``pnv-light.pt`` (``{"num_pcs", "state_dict", "provenance"}``) and
   ``pnv-light.json`` (the provenance and the file's SHA-256).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ssga_core import InputError
from ssga_bench import TrainingRun, atomic_write_bytes, cached_homes, checkpoint_bytes, load_checkpoint, training_main
from ssga_bench import training_log as log
from ssga_descriptor_pnv.evaluate import HeldOut, evaluate, render_heldout
from ssga_descriptor_pnv.homes import Places, relations, render_places
from ssga_workspace_procedural.training_homes import BENCH_HOME, RENDERER_VERSION
from ssga_descriptor_pnv.layout import LIGHT_WIDTHS
from ssga_descriptor_pnv.model import PatchNetVLAD, preprocess

MODULE = "ssga_descriptor_pnv.train"
EXPORT_NAME = "pnv-light"


@dataclass(frozen=True)
class TrainConfig:
    """Everything a run depends on (stored in ``--out`` and in the exported weights)."""

    train_seeds: tuple[int, ...] = tuple(range(1000, 1008))
    places_per_home: int = 250
    jitter_m: float = 0.5
    jitter_deg: float = 20.0
    positive_m: float = 1.0
    positive_deg: float = 30.0
    negative_m: float = 3.0
    negative_deg: float = 90.0
    widths: tuple[int, ...] = LIGHT_WIDTHS
    clusters: int = 16
    num_pcs: int = 512
    stages: tuple[tuple[int, int], ...] = ((128, 900), (256, 40))
    """(image size, optimiser steps) of each stage."""
    lr: tuple[float, ...] = (3e-4, 1e-4)
    """Adam's learning rate in each stage."""
    places_per_batch: int = 12
    homes_per_batch: int = 2
    hard_negatives: int = 5
    margin: float = 0.1
    brightness: float = 0.2
    """Per-view photometric jitter: gain and offset drawn within +-this."""
    kmeans_images: int = 400
    kmeans_per_image: int = 64
    pca_images: int = 1500
    heldout: HeldOut = field(default_factory=HeldOut)
    checkpoint_every: int = 50
    seed: int = 0


class Run(TrainingRun):
    """One training run in ``out``: its caches, checkpoints and timings."""

    config: TrainConfig

    module = MODULE
    export_name = EXPORT_NAME
    what = "light Patch-NetVLAD (VGG16 layout, block widths 16/32/64/128/128) trained on procedural homes"

    # ------------------------------------------------------------------ views

    def training_data(self) -> Places:
        c = self.config
        # Place ids run on from one home to the next, so the homes' order is part of every home's views.
        settings = {"homes": list(c.train_seeds), "places_per_home": c.places_per_home, "jitter": [c.jitter_m, c.jitter_deg], "renderer": RENDERER_VERSION}

        def render(seed: int) -> Places:
            first = c.train_seeds.index(seed) * c.places_per_home
            return render_places(seed, c.places_per_home, jitter_m=c.jitter_m, jitter_deg=c.jitter_deg, first_place=first)

        return self.cached("render", lambda folder: cached_homes(folder, "places", c.train_seeds, settings, render, Places, progress=log))

    # ------------------------------------------------------------------ init

    def network(self) -> PatchNetVLAD:
        return PatchNetVLAD(self.config.widths, self.config.clusters, self.config.num_pcs)

    def initial(self, data: Places) -> PatchNetVLAD:
        """The seeded network with k-means centroids (cached as ``init.pt``: the random-init baseline)."""
        c = self.config
        path = self.out / "init.pt"
        if path.is_file():
            net = PatchNetVLAD(c.widths, c.clusters, c.num_pcs)
            net.load_state_dict(load_checkpoint(path, "init")["state_dict"])
            return net
        t = time.perf_counter()
        torch.manual_seed(c.seed)
        net = PatchNetVLAD(c.widths, c.clusters, c.num_pcs)
        rng = np.random.default_rng([c.seed, 1])
        chosen = rng.choice(len(data), min(c.kmeans_images, len(data)), replace=False)
        size = c.stages[0][0]
        descs = []
        with torch.inference_mode():
            for s in range(0, len(chosen), 16):
                x = torch.cat([preprocess(im, size) for im in data.rgb[np.sort(chosen[s : s + 16])]])
                f = F.normalize(net.encoder(x), dim=1).flatten(2).transpose(1, 2)  # (N, HW, D)
                for d in f.numpy():
                    descs.append(d[rng.choice(len(d), min(c.kmeans_per_image, len(d)), replace=False)])
        descs = np.concatenate(descs).astype(np.float32)
        centroids = _kmeans(descs, c.clusters, c.seed)
        net.pool.init_from(centroids, descs)
        atomic_write_bytes(path, checkpoint_bytes({"state_dict": net.state_dict(), "wpca_fitted": False}))
        self.timed("init", time.perf_counter() - t)
        log(f"centroids: k-means of {len(descs)} conv5_3 descriptors into {c.clusters} clusters ({time.perf_counter() - t:.0f} s)")
        return net

    # ------------------------------------------------------------------ training

    metrics = ("loss", "violating_triplets")

    def batch_size(self, stage: int) -> int:
        return 2 * (self.config.places_per_batch // self.config.homes_per_batch) * self.config.homes_per_batch

    def begin_stage(self, stage: int, data: Places) -> tuple[Places, np.ndarray, dict, dict]:
        """The views at the stage's size, and where each home's places and each place's two views are."""
        by_home = {h: np.unique(data.place[data.home == h]) for h in self.config.train_seeds}
        first_view = np.r_[0, np.flatnonzero(data.place[1:] != data.place[:-1]) + 1]  # index of each place's first view
        return data, _resized(data.rgb, self.config.stages[stage][0]), by_home, dict(zip(data.place[first_view], first_view))

    def train_step(self, net, optimizer, stage, data, rng) -> tuple[float, float]:
        c = self.config
        places_data, images, by_home, place_start = data
        homes = rng.choice(c.train_seeds, c.homes_per_batch, replace=False)
        per_home = c.places_per_batch // c.homes_per_batch
        places = np.concatenate([rng.choice(by_home[h], per_home, replace=False) for h in homes])
        idx = np.stack([[place_start[p], place_start[p] + 1] for p in places]).ravel()
        return _step(net, optimizer, images[idx], places_data, idx, c, rng)

    # ------------------------------------------------------------------ after training

    def after_training(self, net: PatchNetVLAD, data: Places) -> dict[str, Any]:
        return {"wpca": self.fit_wpca(net, data)}

    def heldout_figures(self, init: PatchNetVLAD, net: PatchNetVLAD) -> dict[str, Any]:
        """Recall@N of the initialisation (before WPCA: it has none) and the result on held-out homes."""
        heldout = render_heldout(self.config.heldout)
        return {"init": evaluate(init, heldout, self.config.heldout, wpca=False), "trained": evaluate(net, heldout, self.config.heldout)}

    def provenance_extra(self, net: PatchNetVLAD) -> dict[str, Any]:
        return {"train_seeds": list(self.config.train_seeds), "heldout_seeds": list(self.config.heldout.seeds), "home": dict(BENCH_HOME)}

    def payload(self, net: PatchNetVLAD) -> dict[str, Any]:
        return {"num_pcs": net.num_pcs, "state_dict": net.state_dict()}

    def fit_wpca(self, net: PatchNetVLAD, data: Places) -> dict[str, float]:
        c = self.config
        path = self.out / "wpca.pt"
        if path.is_file():
            done = load_checkpoint(path, "WPCA")
            net.load_state_dict(done["state_dict"])
            return dict(done["figures"])
        rng = np.random.default_rng([c.seed, 3])
        chosen = np.sort(rng.choice(len(data), min(c.pca_images, len(data)), replace=False))
        t = time.perf_counter()
        net.eval()
        g = []
        with torch.inference_mode():
            for s in range(0, len(chosen), 16):
                x = torch.cat([preprocess(im, 256) for im in data.rgb[chosen[s : s + 16]]])
                g.append(net.global_vlad(x).numpy())
        figures = fit_wpca(net, np.concatenate(g).astype(np.float64))
        atomic_write_bytes(path, checkpoint_bytes({"state_dict": net.state_dict(), "figures": figures}))
        self.timed("wpca", time.perf_counter() - t)
        log(f"WPCA: {len(chosen)} descriptors -> {c.num_pcs} dims, {figures['explained_variance']:.1%} of the variance ({time.perf_counter() - t:.0f} s)")
        return figures


def fit_wpca(net: PatchNetVLAD, descriptors: np.ndarray) -> dict[str, float]:
    """Set ``net.WPCA`` to PCA whitening of ``descriptors`` ``(N, K * D)``: ``y = diag(1 / sqrt(lambda)) U^T (x - mu)``.

    Eigenvalues and vectors of the covariance (``N - 1`` normalised) via an SVD of the
    centred data; each component is scaled by ``1 / sqrt(lambda + 1e-9)`` (the reference's).
    """
    num_pcs = net.num_pcs
    n = len(descriptors)
    if n <= num_pcs:
        raise InputError(f"WPCA to {num_pcs} dimensions needs more than {num_pcs} descriptors, got {n}")
    mu = descriptors.mean(axis=0)
    _, s, vt = np.linalg.svd(descriptors - mu, full_matrices=False)
    lams = s**2 / (n - 1)
    u = vt[:num_pcs].T / np.sqrt(lams[:num_pcs] + 1e-9)  # (K * D, num_pcs)
    conv = net.WPCA[0]
    with torch.no_grad():
        conv.weight.copy_(torch.from_numpy(u.T.astype(np.float32))[:, :, None, None])
        conv.bias.copy_(torch.from_numpy((-u.T @ mu).astype(np.float32)))
    return {"explained_variance": float(lams[:num_pcs].sum() / lams.sum()), "descriptors": n}


def _kmeans(x: np.ndarray, k: int, seed: int) -> np.ndarray:
    from ssga_bench import BagOfWords, BoWConfig

    bow = BagOfWords(BoWConfig(k=k, prototypes=1, iterations=100, seed=seed, max_train=len(x))).fit(x)
    assert bow.centroids is not None
    return bow.centroids


def _resized(rgb: np.ndarray, size: int) -> np.ndarray:
    """``rgb`` at ``size`` x ``size`` (uint8), resized as :func:`preprocess` resizes."""
    if rgb.shape[1:3] == (size, size):
        return rgb
    out = np.empty((len(rgb), size, size, 3), dtype=np.uint8)
    for s in range(0, len(rgb), 256):
        x = torch.from_numpy(rgb[s : s + 256]).permute(0, 3, 1, 2).float()
        y = F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False, antialias=True)
        out[s : s + 256] = y.round().clamp(0, 255).byte().permute(0, 2, 3, 1).numpy()
    return out


def _step(net: PatchNetVLAD, optimizer, rgb: np.ndarray, data: Places, idx: np.ndarray, c: TrainConfig, rng) -> tuple[float, float]:
    """One optimiser step on a batch of place pairs (consecutive views ``2 i``, ``2 i + 1``)."""
    x = torch.cat([preprocess(im, None) for im in rgb])
    gain = torch.from_numpy(rng.uniform(1 - c.brightness, 1 + c.brightness, (len(x), 1, 1, 1)).astype(np.float32))
    offset = torch.from_numpy(rng.uniform(-c.brightness, c.brightness, (len(x), 1, 1, 1)).astype(np.float32))
    x = x * gain + offset
    desc = net.global_vlad(x)
    # Unit vectors: |a - b|^2 = 2 - 2 a.b (cdist's backward is NaN at the zero diagonal).
    dist = (2.0 - 2.0 * desc @ desc.T).clamp_min(1e-12).sqrt()
    _, negative = relations(
        data.poses[idx], data.home[idx], data.poses[idx], data.home[idx],
        positive_m=c.positive_m, positive_deg=c.positive_deg, negative_m=c.negative_m, negative_deg=c.negative_deg,
    )
    mate = np.arange(len(idx)) ^ 1
    d_pos = dist[np.arange(len(idx)), mate]
    d_neg = dist.masked_fill(~torch.from_numpy(negative), float("inf"))
    nearest, _ = d_neg.topk(c.hard_negatives, dim=1, largest=False)
    valid = torch.isfinite(nearest)
    terms = F.relu(d_pos[:, None] - nearest + c.margin**0.5)[valid]
    if not len(terms):  # no negative in the batch (a tiny home): nothing to learn from
        return 0.0, 0.0
    loss = terms.mean()
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    return loss.item(), (terms > 0).float().mean().item()


def main(argv: Sequence[str] | None = None) -> int:
    return training_main(MODULE, __doc__, run_training, TrainConfig(), argv, exports=f"{EXPORT_NAME}.pt and {EXPORT_NAME}.json")


run_training = Run.run_training
"""Every step of the module docstring; returns what was exported."""


if __name__ == "__main__":
    sys.exit(main())
