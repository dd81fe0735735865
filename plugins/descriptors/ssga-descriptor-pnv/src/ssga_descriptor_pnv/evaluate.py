"""Held-out place recognition with whole-image descriptors: is a trained network better than its init?

Two held-out procedural homes (seeds no training run and no benchmark uses), each
with ``places`` places of two views: the first of each place goes to the database,
the second, up to ``jitter_m`` / ``jitter_deg`` away, is a query. Each query's
nearest database views by Euclidean distance between whole-image descriptors count
as correct if one of the first N stands within ``correct_m`` and ``correct_deg`` of
the query in the same home (Recall@N; the query's own place always qualifies). The
database holds both homes' views, so a query can also go wrong to the other home.

    python -m ssga_descriptor_pnv.evaluate --weights pnv-light.pt [--weights runs/pnv-light/init.pt]

Descriptors: ``netvlad``, the global NetVLAD before WPCA (what training compares;
comparable between a trained network and its initialisation), and ``wpca``, after
the WPCA layer (only meaningful once WPCA has been fitted).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ssga_descriptor_pnv.homes import Places, relations, render_places
from ssga_descriptor_pnv.model import PatchNetVLAD, preprocess

HELDOUT_SEEDS = (1100, 1101)
"""Held-out homes: never trained on (training uses 1000-1007), never benchmarked (0, 1, 2)."""


@dataclass(frozen=True)
class HeldOut:
    seeds: tuple[int, ...] = HELDOUT_SEEDS
    places: int = 150
    jitter_m: float = 1.0
    jitter_deg: float = 30.0
    correct_m: float = 1.0
    correct_deg: float = 30.0
    size: int = 256


def render_heldout(spec: HeldOut = HeldOut(), progress=None) -> Places:
    parts = [
        render_places(s, spec.places, jitter_m=spec.jitter_m, jitter_deg=spec.jitter_deg, first_place=i * spec.places, progress=progress)
        for i, s in enumerate(spec.seeds)
    ]
    return Places.concat(parts)


def global_descriptors(net: PatchNetVLAD, rgb: np.ndarray, size: int, *, wpca: bool, batch: int = 16) -> np.ndarray:
    """``(N, dim)`` whole-image descriptors of ``rgb`` ``(N, H, W, 3)`` at ``size`` x ``size``."""
    net.eval()
    out = []
    with torch.inference_mode():
        for s in range(0, len(rgb), batch):
            x = torch.cat([preprocess(im, size) for im in rgb[s : s + batch]])
            g = net.global_vlad(x)
            out.append((net.wpca(g) if wpca else g).numpy())
    return np.concatenate(out)


def recall_at(descriptors: np.ndarray, data: Places, spec: HeldOut, ns: Sequence[int] = (1, 5)) -> dict[str, float]:
    """Recall@N of the second view of each place against the first views of all places."""
    db = np.flatnonzero(np.r_[True, data.place[1:] != data.place[:-1]])
    q = db + 1
    d = ((descriptors[q, None, :] - descriptors[None, db, :]) ** 2).sum(-1)
    order = np.argsort(d, axis=1, kind="stable")
    correct, _ = relations(
        data.poses[q], data.home[q], data.poses[db], data.home[db],
        positive_m=spec.correct_m, positive_deg=spec.correct_deg, negative_m=0.0, negative_deg=0.0,
    )
    hits = np.take_along_axis(correct, order, axis=1)
    return {f"recall@{n}": float(hits[:, :n].any(axis=1).mean()) for n in ns}


def evaluate(net: PatchNetVLAD, data: Places, spec: HeldOut = HeldOut(), *, wpca: bool = True) -> dict[str, dict[str, float]]:
    """``{"netvlad": {...}, "wpca": {...}}`` recalls of ``net`` on the held-out views (``wpca`` only if asked)."""
    g = global_descriptors(net, data.rgb, spec.size, wpca=False)
    out = {"netvlad": recall_at(g, data, spec)}
    if wpca:
        with torch.inference_mode():
            out["wpca"] = recall_at(net.wpca(torch.from_numpy(g)).numpy(), data, spec)
    return out


def load_network(path: str) -> tuple[PatchNetVLAD, bool]:
    """A light network from a checkpoint of this package (``pnv-light.pt`` or a training state), and whether it has WPCA."""
    from ssga_bench import load_checkpoint, load_strict
    from ssga_descriptor_pnv.plugin import WEIGHTS_DIR

    file = Path(path)
    if not file.is_file() and (WEIGHTS_DIR / path).is_file():
        file = WEIGHTS_DIR / path
    checkpoint = load_checkpoint(file, "pnv evaluate")
    state = checkpoint["state_dict"]
    widths = tuple(int(state[f"encoder.{i}.weight"].shape[0]) for i in (2, 7, 14, 21, 28))
    net = PatchNetVLAD(widths, int(state["pool.centroids"].shape[0]), int(state["WPCA.0.bias"].shape[0]))
    load_strict(net, state, "pnv evaluate", file)
    return net, bool(checkpoint.get("wpca_fitted", True))


def main(argv: Sequence[str] | None = None) -> int:
    from ssga_bench import evaluation_main

    def measure(weights: str | None, data: Places, args) -> dict[str, dict[str, float]]:
        net, fitted = load_network(weights or "pnv-light.pt")
        return evaluate(net, data, HeldOut(), wpca=fitted)

    return evaluation_main("ssga_descriptor_pnv.evaluate", __doc__, argv, held_out=lambda args: render_heldout(HeldOut(), progress=lambda line: print(line, file=sys.stderr, flush=True)), measure=measure)

if __name__ == "__main__":
    sys.exit(main())
