"""The place classifier of each variant: a graph convolutional network (Kipf & Welling, 2017).

Each layer computes ``H' = ReLU(Â H W)`` with ``Â = D^-1/2 (A + I) D^-1/2``; a masked
mean over the nodes feeds a linear classifier over the place classes. Node features
enter multiplied by their node weight (1 for the whole image, 1/K for each of the K
parts, paper §3.2). Graphs are padded into dense batches: scene graphs have at most a
few hundred nodes, where dense products beat sparse ones on a CPU.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

from ssga_bench.io import atomic_write_bytes
from ssga_core.data import SceneGraph
from ssga_core.errors import CheckpointError

if TYPE_CHECKING:  # the model takes any config with these fields; it does not depend on the config module
    from ssga_bench.config import TrainingConfig


@dataclass(frozen=True)
class GraphBatch:
    """Padded tensors of a list of graphs: features ``(B, N, F)``, normalised adjacency ``(B, N, N)``,
    node mask ``(B, N)`` and node weights ``(B, N)`` (0 on padding)."""

    x: torch.Tensor
    adj: torch.Tensor
    mask: torch.Tensor
    weights: torch.Tensor

    @classmethod
    def of(cls, graphs: Sequence[SceneGraph]) -> GraphBatch:
        if not graphs:
            raise ValueError("GraphBatch.of: no graphs")
        n = max(g.num_nodes for g in graphs)
        f = graphs[0].features.shape[1]
        x = np.zeros((len(graphs), n, f), np.float32)
        adj = np.zeros((len(graphs), n, n), np.float32)
        mask = np.zeros((len(graphs), n), np.float32)
        weights = np.zeros((len(graphs), n), np.float32)
        for b, g in enumerate(graphs):
            k = g.num_nodes
            x[b, :k] = g.features * g.weights[:, None]
            a = np.eye(k, dtype=np.float32)
            a[g.edges[:, 0], g.edges[:, 1]] = 1.0
            a[g.edges[:, 1], g.edges[:, 0]] = 1.0
            d = 1.0 / np.sqrt(a.sum(axis=1))
            adj[b, :k, :k] = a * d[:, None] * d[None, :]
            mask[b, :k] = 1.0
            weights[b, :k] = g.weights
        return cls(torch.from_numpy(x), torch.from_numpy(adj), torch.from_numpy(mask), torch.from_numpy(weights))

    def __len__(self) -> int:
        return self.x.shape[0]

    def take(self, index: torch.Tensor) -> GraphBatch:
        return GraphBatch(self.x[index], self.adj[index], self.mask[index], self.weights[index])


class GCN(nn.Module):
    """Graph classifier: ``layers`` graph convolutions, a readout over the nodes, linear output.

    Readout ``"mean"`` averages the nodes; ``"weighted"`` averages them by node weight,
    so the whole image counts as much as all parts together after the convolutions too
    (the symmetric normalisation divides the whole-image node, joined to every part, by
    its degree).
    """

    def __init__(self, in_dim: int, num_classes: int, hidden: int = 256, layers: int = 2, dropout: float = 0.5, readout: str = "mean") -> None:
        super().__init__()
        if readout not in ("mean", "weighted"):
            raise ValueError(f"GCN readout must be 'mean' or 'weighted', got {readout!r}")
        self.hparams = {"in_dim": in_dim, "num_classes": num_classes, "hidden": hidden, "layers": layers, "dropout": dropout, "readout": readout}
        self.convs = nn.ModuleList(nn.Linear(in_dim if i == 0 else hidden, hidden) for i in range(layers))
        self.dropout = nn.Dropout(dropout)
        self.classifier = nn.Linear(hidden, num_classes)

    def forward(self, batch: GraphBatch) -> torch.Tensor:
        h = batch.x
        for conv in self.convs:
            h = torch.relu(batch.adj @ conv(self.dropout(h)))
        m = (batch.weights if self.hparams["readout"] == "weighted" else batch.mask).unsqueeze(-1)
        pooled = (h * m).sum(dim=1) / m.sum(dim=1).clamp(min=1e-6)
        return self.classifier(self.dropout(pooled))

    @torch.no_grad()
    def predict(self, graphs: Sequence[SceneGraph], batch_size: int = 256) -> np.ndarray:
        """Class probabilities ``(len(graphs), num_classes)``."""
        self.eval()
        out = [torch.softmax(self(GraphBatch.of(graphs[i : i + batch_size])), dim=-1) for i in range(0, len(graphs), batch_size)]
        return torch.cat(out).numpy() if out else np.zeros((0, self.hparams["num_classes"]), np.float32)


@dataclass(frozen=True)
class TrainingReport:
    epochs: int
    best_epoch: int
    train_loss: list[float]
    val_loss: list[float]
    """Empty when no class had a second graph to hold out."""


def validation_split(labels: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Indices held out for early stopping: ``fraction`` of each class's graphs, never its last one.

    A class with a single training graph (every class of a variant without S) keeps it,
    so such variants train without validation and stop when the training loss does.
    """
    held: list[int] = []
    for c in np.unique(labels):
        idx = rng.permutation(np.flatnonzero(labels == c))
        held.extend(idx[: min(int(round(fraction * len(idx))), len(idx) - 1)].tolist())
    return np.array(sorted(held), dtype=np.int64)


def train_gcn(
    graphs: Sequence[SceneGraph],
    labels: np.ndarray,
    num_classes: int,
    config: TrainingConfig,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[GCN, TrainingReport]:
    """Train a GCN on labelled graphs with Adam, early stopping on a held-out share of them."""
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    labels = np.asarray(labels, dtype=np.int64)
    val = validation_split(labels, config.validation_fraction, rng)
    train = np.setdiff1d(np.arange(len(graphs)), val)
    batch = GraphBatch.of(graphs)
    y = torch.from_numpy(labels)
    model = GCN(batch.x.shape[-1], num_classes, config.hidden, config.layers, config.dropout, config.readout)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    loss_fn = nn.CrossEntropyLoss()
    train_t, val_t = torch.from_numpy(train), torch.from_numpy(val)
    best, best_epoch, best_state = float("inf"), 0, None
    history_train: list[float] = []
    history_val: list[float] = []
    for epoch in range(1, config.epochs + 1):
        model.train()
        order = train_t[torch.randperm(len(train_t))]
        total = 0.0
        for start in range(0, len(order), 64):
            idx = order[start : start + 64]
            optimiser.zero_grad()
            loss = loss_fn(model(batch.take(idx)), y[idx])
            loss.backward()
            optimiser.step()
            total += loss.item() * len(idx)
        history_train.append(total / len(order))
        model.eval()
        with torch.no_grad():
            monitored = float(loss_fn(model(batch.take(val_t)), y[val_t])) if len(val_t) else history_train[-1]
        if len(val_t):
            history_val.append(monitored)
        if monitored < best - 1e-4:
            best, best_epoch = monitored, epoch
            best_state = {k: v.clone() for k, v in model.state_dict().items()}
        if progress is not None:
            progress(epoch, config.epochs)
        if epoch - best_epoch >= config.patience:
            break
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    return model, TrainingReport(len(history_train), best_epoch, history_train, history_val)


def save_gcn(model: GCN, path: str | Path) -> None:
    """Save ``{"hparams", "state_dict"}`` atomically."""
    buffer = io.BytesIO()
    torch.save({"hparams": model.hparams, "state_dict": model.state_dict()}, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def load_gcn(path: str | Path) -> GCN:
    """Load a checkpoint written by :func:`save_gcn` (weights only, strict)."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        model = GCN(**ckpt["hparams"])
        model.load_state_dict(ckpt["state_dict"], strict=True)
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such GCN checkpoint") from None
    except Exception as exc:  # noqa: BLE001 - whatever torch raises, the file is not a usable checkpoint
        detail = " ".join(str(exc).split())[:300]
        raise CheckpointError(f"{path}: not a GCN checkpoint written by ssga ({type(exc).__name__}: {detail})") from None
    model.eval()
    return model
