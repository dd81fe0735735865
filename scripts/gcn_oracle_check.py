#!/usr/bin/env python
"""Does the GCN learn when the features are informative? Whole image + parts (PD) against whole image only (D).

An oracle check of the place classifier alone: no synthesis, every training view is a
true render. On the demo workspace (or any dataset folder of a workspace that can
render), for every class:

* the class's true view at its training viewpoint (the dataset's ``train`` and
  ``target`` splits) and ``--jitters`` renders at jittered poses around it;
* graphs by the ``slico`` parser and the ``dense-sift`` descriptor, fitted on the
  training viewpoints' views: variant ``PD`` (whole image + parts) and ``D`` (whole
  image only), the same views for both;
* each classifier trained on them (one validation group per rendered pose) and scored
  on the dataset's ``test`` views (MRR over all levels, :mod:`ssga_bench.evaluation`).

Classifiers: ``old`` is the implementation before the packed, standardised GCN (read
from git at ``OLD_COMMIT``) at its defaults; ``new`` is :func:`ssga_bench.gcn.train_gcn`
at :class:`~ssga_bench.config.TrainingConfig`'s defaults; ``--ablations`` adds the new
implementation with one setting changed at a time. Built graphs are cached in ``--out``
(the renders take a minute or two), so reruns only train; delete the cache after
changing a stage. Per-epoch times include packing and the final evaluation.

    .venv/bin/python scripts/gcn_oracle_check.py --jitters 8 --ablations
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import pickle
import sys
import time
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import numpy as np
import torch
from ssga_bench.cache import FeatureCache
from ssga_bench.config import TrainingConfig
from ssga_bench.dataset import Dataset
from ssga_bench.evaluation import metrics, truth_ranks
from ssga_bench.gcn import train_gcn
from ssga_bench.training_plan import jittered
from ssga_core.config import resolve_stage
from ssga_core.pipeline import BoundVariant, build_graph
from ssga_core.plugins import default_registry
from ssga_core.variants import parse_variant

from history import module_at

OLD_COMMIT = "03b8d7f"
"""The last commit with the dense-batch GCN (mean readout, no input statistics)."""
OLD_DEFAULTS = {"hidden": 256, "layers": 2, "dropout": 0.5, "readout": "mean", "epochs": 200, "lr": 1e-3,
                "weight_decay": 5e-4, "patience": 20, "validation_fraction": 0.2}  # fmt: skip
ABLATIONS = {
    "new, readout=mean": {"readout": "mean"},
    "new, node_weights=readout": {"node_weights": "readout"},
    "new, dropout=0.5 wd=5e-4": {"dropout": 0.5, "weight_decay": 5e-4},
    "new, batch_size=256": {"batch_size": 256},
}
VARIANTS = ("D", "PD")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    head, _, rest = __doc__.partition("\n\n")
    p = argparse.ArgumentParser(description=head, epilog=rest, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--dataset", default="runs/workspaces/procedural-0-dd0941a0", help="a dataset folder of a renderable workspace"
    )
    p.add_argument("--jitters", type=int, default=8, help="jittered renders per class beside its training viewpoint [8]")
    p.add_argument("--jitter-m", type=float, default=0.5, help="jittered poses move up to this far, metres [0.5]")
    p.add_argument("--jitter-deg", type=float, default=10.0, help="...and turn up to this much, degrees [10]")
    p.add_argument("--seed", type=int, default=0, help="seed of the jitters and of training [0]")
    p.add_argument("--threads", type=int, default=1, help="torch threads for every classifier, old and new [1]")
    p.add_argument("--out", default="runs/gcn-oracle", help="folder for the graph cache and results.json [runs/gcn-oracle]")
    p.add_argument("--ablations", action="store_true", help="also train the new classifier with one setting changed at a time")
    p.add_argument("--no-old", action="store_true", help="skip the old implementation")
    return p.parse_args(argv)


def build_graphs(args: argparse.Namespace) -> dict[str, Any]:
    """Training and test graphs of both variants, their labels and the training views' pose groups."""
    dataset = Dataset.open(args.dataset)
    registry = default_registry()
    source = dict(dataset.header["source"])
    workspace = registry.create("workspace", source.pop("name"), **source).open()
    rng = np.random.default_rng(args.seed)
    canonical = sorted(dataset.split("train") + dataset.split("target"), key=lambda s: s.place)
    views, labels = [], []
    for n, s in enumerate(canonical, 1):
        views.append(dataset.view(s))
        views.extend(workspace.render(jittered(s.pose, rng, args.jitter_m, args.jitter_deg)) for _ in range(args.jitters))
        labels.extend([s.place] * (1 + args.jitters))
        print(f"\rrendered {n}/{len(canonical)} classes", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    parser = resolve_stage("parser", {"name": "slico"}, registry).create()
    descriptor = resolve_stage("descriptor", {"name": "dense-sift"}, registry).create()
    descriptor.fit(views[:: 1 + args.jitters], labels[:: 1 + args.jitters])  # the training viewpoints, as the runner fits
    memo = FeatureCache()  # D and PD describe the same views once
    tests = dataset.split("test")
    test_views = [dataset.view(s) for s in tests]
    out: dict[str, Any] = {
        "train_labels": np.array(labels),
        "groups": np.arange(len(labels)),  # every render stands at a pose of its own
        "test_labels": np.array([s.place for s in tests]),
        "num_classes": dataset.num_classes,
    }
    for variant in VARIANTS:
        bound = BoundVariant(parse_variant(variant), descriptor=descriptor, parser=parser if "P" in variant else None)
        out[variant] = ([build_graph(bound, v, memo=memo) for v in views], [build_graph(bound, v, memo=memo) for v in test_views])
        print(f"built {variant} graphs", file=sys.stderr)
    return out


def cached_graphs(args: argparse.Namespace) -> dict[str, Any]:
    key = json.dumps([args.dataset, args.jitters, args.jitter_m, args.jitter_deg, args.seed])
    path = Path(args.out) / f"graphs-{hashlib.blake2b(key.encode(), digest_size=6).hexdigest()}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    data = build_graphs(args)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(data))
    return data


@functools.cache
def old_module() -> ModuleType:
    return module_at(OLD_COMMIT, "ssga_bench/src/ssga_bench/gcn.py", "old_gcn")


def train_one(
    name: str, graphs: list, labels: np.ndarray, groups: np.ndarray, num_classes: int, seed: int, threads: int
) -> tuple[Any, dict[str, Any]]:
    """Train classifier ``name``; return it and what to report of its training."""
    torch.set_num_threads(threads)
    start = time.perf_counter()
    if name == "old":
        config = SimpleNamespace(**OLD_DEFAULTS, seed=seed)
        model, report = old_module().train_gcn(graphs, labels, num_classes, config)
        cap = config.epochs
        info = {"stopped_at_cap": report.epochs == cap and report.epochs - report.best_epoch < config.patience}
    else:
        config = TrainingConfig(seed=seed, threads=threads, **(ABLATIONS.get(name, {})))
        model, report = train_gcn(graphs, labels, num_classes, config, groups=groups)
        info = {"stopped_at_cap": report.stopped_at_cap}
    seconds = time.perf_counter() - start
    train_acc = float((model.predict(graphs).argmax(axis=1) == labels).mean())
    return model, {**info, "epochs": report.epochs, "best_epoch": report.best_epoch, "train_acc": 100 * train_acc,
                   "s_per_epoch": seconds / report.epochs, "seconds": seconds}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    data = cached_graphs(args)
    names = ([] if args.no_old else ["old"]) + ["new"] + (list(ABLATIONS) if args.ablations else [])
    rows = []
    for variant in VARIANTS:
        train, test = data[variant]
        for name in names:
            model, row = train_one(
                name, train, data["train_labels"], data["groups"], data["num_classes"], args.seed, args.threads
            )
            m = metrics(truth_ranks(model.predict(test), data["test_labels"]))
            rows.append({"variant": variant, "classifier": name, **row, "test_mrr": m["mrr"], "test_top1": m["top1"]})
            print(json.dumps(rows[-1]), file=sys.stderr)
    nodes = {v: float(np.mean([g.num_nodes for g in data[v][0]])) for v in VARIANTS}
    print(f"{len(data['train_labels'])} training graphs, {len(data['test_labels'])} test views, {data['num_classes']} classes; "
          f"mean nodes per graph: " + ", ".join(f"{v} {n:.1f}" for v, n in nodes.items()))  # fmt: skip
    print("| variant | classifier | train acc % | epochs (best) | stopped by | test MRR % | test top-1 % | s/epoch |")
    print("|---|---|---:|---:|---|---:|---:|---:|")
    for r in rows:
        stop = "epoch cap" if r["stopped_at_cap"] else "early stop"
        print(f"| {r['variant']} | {r['classifier']} | {r['train_acc']:.1f} | {r['epochs']} ({r['best_epoch']}) | {stop} | "
              f"{r['test_mrr']:.1f} | {r['test_top1']:.1f} | {r['s_per_epoch']:.3f} |")  # fmt: skip
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "results.json").write_text(json.dumps({"args": vars(args), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
