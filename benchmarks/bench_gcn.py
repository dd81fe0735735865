"""Speed of the GCN place classifier (``make bench``): seconds per training epoch.

2000 scene graphs as the pipeline makes them (whole image + 0-39 parts, edges by box
proximity, node weights 1 and 1/K), 100-dimensional L2-normalised bag-of-words
features sharing a common direction, 120 classes; one epoch is one pass of Adam over
them in batches of 64, on one torch thread (``TrainingConfig.threads``'s default) and
on two.

* ``old``: the implementation before the packed one, kept here only to be measured:
  graphs padded into dense ``(B, N, N)`` batches, ``Â H W`` per layer, mean readout;
* ``new``: :mod:`ssga_bench.gcn` at :class:`~ssga_bench.config.TrainingConfig`'s
  defaults: one packed node table, a block-diagonal sparse ``Â``, the first layer's
  inputs computed once, the last layer on pooled rows.

Measured on the 2-core dev machine, nearly idle: one thread, old 1.1-1.3 s and new
0.26-0.28 s per epoch (4-5x); two threads, old 0.87-1.07 s and new 0.25-0.29 s. While
other jobs held the cores, one thread gave old 1.1-1.6 s and new ~0.4 s, and two threads
were several times slower than one (old 6-10 s), hence ``TrainingConfig.threads = 1``.
Packing the 2000 graphs takes ~30 ms, once per training.
Run alone with
``pytest benchmarks/bench_gcn.py -o python_files='bench_*.py' --benchmark-enable``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from ssga_bench.config import TrainingConfig
from ssga_bench.gcn import GCN, PackedGraphs
from ssga_bench.learned import torch_threads
from ssga_core.geometry import Camera
from ssga_core.graph import assemble
from torch import nn
from torch.nn import functional as F

from ssga_core import SceneGraph

GRAPHS, FEATURES, CLASSES, BATCH = 2000, 100, 120, 64


def realistic_graphs(seed: int = 0) -> tuple[list[SceneGraph], np.ndarray]:
    rng = np.random.default_rng(seed)
    common = rng.random(FEATURES)
    prototypes = common + 0.5 * rng.random((CLASSES, FEATURES))
    graphs, labels = [], rng.integers(0, CLASSES, GRAPHS)
    for c in labels:
        k = int(rng.integers(0, 40))
        corner = rng.uniform(0, 220, (k, 2))
        features = np.abs(prototypes[c] + 0.3 * rng.standard_normal((k + 1, FEATURES)))
        features /= np.linalg.norm(features, axis=1, keepdims=True)
        graphs.append(
            assemble(
                Camera(), np.concatenate([corner, corner + rng.uniform(10, 60, (k, 2))], axis=1), features.astype(np.float32)
            )
        )
    return graphs, labels


class OldGraphBatch:
    """The old padded batch: features times node weight ``(B, N, F)``, ``Â`` ``(B, N, N)``, node mask ``(B, N)``."""

    def __init__(self, graphs: list[SceneGraph]) -> None:
        n, f = max(g.num_nodes for g in graphs), graphs[0].features.shape[1]
        self.x = torch.zeros(len(graphs), n, f)
        self.adj = torch.zeros(len(graphs), n, n)
        self.mask = torch.zeros(len(graphs), n)
        for b, g in enumerate(graphs):
            k = g.num_nodes
            a = np.eye(k, dtype=np.float32)
            a[g.edges[:, 0], g.edges[:, 1]] = a[g.edges[:, 1], g.edges[:, 0]] = 1.0
            d = 1.0 / np.sqrt(a.sum(axis=1))
            self.x[b, :k] = torch.from_numpy(g.features * g.weights[:, None])
            self.adj[b, :k, :k] = torch.from_numpy(a * d[:, None] * d[None, :])
            self.mask[b, :k] = 1.0


class OldGCN(nn.Module):
    """The old forward: ``ReLU(Â (dropout(H) W))`` per layer, a masked mean, a linear classifier."""

    def __init__(self, in_dim: int, num_classes: int, hidden: int = 256, layers: int = 2, dropout: float = 0.5) -> None:
        super().__init__()
        self.convs = nn.ModuleList(nn.Linear(in_dim if i == 0 else hidden, hidden) for i in range(layers))
        self.dropout = nn.Dropout(dropout)
        self.classifier = nn.Linear(hidden, num_classes)

    def forward(self, x: torch.Tensor, adj: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        h = x
        for conv in self.convs:
            h = torch.relu(adj @ conv(self.dropout(h)))
        m = mask.unsqueeze(-1)
        return self.classifier(self.dropout((h * m).sum(dim=1) / m.sum(dim=1).clamp(min=1e-6)))


@pytest.fixture(scope="module")
def data() -> tuple[list[SceneGraph], torch.Tensor]:
    graphs, labels = realistic_graphs()
    return graphs, torch.from_numpy(labels)


def _epoch(model: nn.Module, optimiser: torch.optim.Optimizer, step_inputs, labels: torch.Tensor) -> None:
    model.train()
    for idx in torch.randperm(len(labels)).split(BATCH):
        loss = F.cross_entropy(model(*step_inputs(idx)), labels[idx])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()


def _record(benchmark, threads: int) -> None:
    benchmark.extra_info["threads"] = threads
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        benchmark.extra_info["s_per_epoch"] = round(stats.stats.median, 3)


@pytest.mark.parametrize("threads", [1, 2])
def test_epoch_old_dense(benchmark, data, threads):
    """The old implementation at the old defaults (dropout 0.5, weight decay 5e-4); batches padded to the largest graph."""
    graphs, labels = data
    batch = OldGraphBatch(graphs)
    torch.manual_seed(0)
    model = OldGCN(FEATURES, CLASSES)
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-3, weight_decay=5e-4)
    with torch_threads(threads):
        benchmark.pedantic(
            _epoch, (model, optimiser, lambda i: (batch.x[i], batch.adj[i], batch.mask[i]), labels), rounds=3, warmup_rounds=1
        )
    _record(benchmark, threads)


@pytest.mark.parametrize("threads", [1, 2])
def test_epoch_new_packed(benchmark, data, threads):
    """:func:`ssga_bench.gcn.train_gcn`'s epoch at the default config."""
    graphs, labels = data
    packed = PackedGraphs.of(graphs)
    config = TrainingConfig()
    torch.manual_seed(0)
    model = GCN(FEATURES, CLASSES, config.hidden, config.layers, config.dropout, config.readout, config.node_weights)
    model.fit_inputs(packed)
    packed = model.prepare(packed)  # as train_gcn does: the first layer's inputs once
    optimiser = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    with torch_threads(threads):
        benchmark.pedantic(_epoch, (model, optimiser, lambda i: (packed.take(i),), labels), rounds=3, warmup_rounds=1)
    _record(benchmark, threads)


def test_pack_2000_graphs(benchmark, data):
    """Packing is done once per training (and once per prediction)."""
    packed = benchmark(PackedGraphs.of, data[0])
    assert len(packed) == GRAPHS
