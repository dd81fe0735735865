"""The place classifier of each variant: a graph convolutional network over scene graphs (paper §3.2).

The model, in the order the data flows:

1. **Standardised inputs.** Node features are bag-of-words histograms that share most of
   their length in one direction (cosine ~0.66 between classes on the demo): raw, they
   leave the first layer a small signal on a large offset, and the network underfits.
   Each feature is centred and scaled by statistics of the training graphs, fitted
   separately for whole-image nodes and for parts (a part pools far fewer local
   features, so its histograms are sparser). The statistics are buffers of the model:
   a checkpoint carries them and scores the same after loading.
2. **Node weights** (paper §3.2: the whole image 1, each of the K parts 1/K) scale the
   standardised features (``node_weights="input"``, the paper's recipe, the default) or
   only weigh the parts in the readout (``"readout"``); neither won when measured
   (``scripts/gcn_oracle_check.py``: PD test MRR 84.2 both; the demo: 21.7 against 21.3,
   mean over its five P variants).
3. **Graph convolutions** ``H' = ReLU([H, ÂH] W + b)`` with ``Â = D^-1/2 (A + I) D^-1/2``:
   each node keeps a weight of its own beside its neighbourhood's. This is Kipf & Welling's
   first-order filter ``θ0 x + θ1 Â x`` before they tie ``θ0 = θ1``; tied, the whole-image
   node, joined to every part, keeps ``1/(K+1)`` of its own state after one layer and
   drowns in its K parts.
4. **Readout** ``"image+parts"`` (the default): the whole image's state beside the
   weighted mean of the parts' states (zeros for a graph without parts), then a linear
   classifier. Parts add a summary to the whole image instead of outvoting it: a plain
   mean over 1 + K nodes gave the whole image 1/(K+1) of the pooled state (2.6% on
   slico graphs). ``"mean"`` and ``"weighted"`` (all nodes, by count or by node weight)
   remain for comparison. The last layer's ReLU comes after the pooling (see
   :meth:`GCN.forward`), so that layer costs one row per graph, not one per node.
5. **Head** ``"linear"`` (the paper's): a linear layer over the pooled state. ``"cosine"``:
   a scaled cosine between the pooled state and one prototype per class, the prototypes
   started at the mean pooled state of each class's training graphs (:meth:`GCN.start_prototypes`),
   so a class is first scored by how like its own graphs a query is, as nearest neighbour
   does, and training moves the prototypes from there.

Training (:func:`train_gcn`): Adam, early stopping on the validation loss of a held-out
share of the graphs, whole pose groups at a time (:func:`validation_split`), or on the
training loss where no class can spare a group. Graphs are packed once into one node
table and one block-diagonal sparse adjacency, with no padding; a mini-batch is a few
vectorised index operations on them (:meth:`PackedGraphs.take`), and what the first
layer reads is computed once (:meth:`GCN.prepare`). On one torch thread by default: on
the 2-core machine two threads were at most 1.5x faster while nothing else ran, and
several times slower while another process held a core.
``scripts/gcn_oracle_check.py`` and ``benchmarks/bench_gcn.py`` measure all of this.
"""

from __future__ import annotations

import dataclasses
import io
import warnings
from collections import Counter
from collections.abc import Callable, Sequence
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from ssga_core.data import SceneGraph
from ssga_core.errors import CheckpointError
from torch import nn
from torch.nn import functional as F

from ssga_bench.io import atomic_write_bytes
from ssga_bench.learned import torch_threads
from ssga_bench.seeds import stream, torch_seed

if TYPE_CHECKING:  # the model takes any config with these fields; it does not depend on the config module
    from ssga_bench.config import TrainingConfig

READOUTS = ("image+parts", "mean", "weighted")
NODE_WEIGHTS = ("input", "readout")
HEADS = ("linear", "cosine")
COSINE_SCALE = 10.0
"""The cosine head's starting inverse temperature (learned): cosines span [-1, 1], too flat for a softmax over 120 classes."""
CHECKPOINT_FORMAT = 2
"""Format 1 (dense batches, no input statistics) is refused: its weights mean something else."""
SCALE_FLOOR = 0.1
"""A feature's scale is at least this share of the mean scale: a word (nearly) absent from
the training graphs is not blown up into noise where a test graph has it."""
MIN_IMPROVEMENT = 1e-4
"""The monitored loss must drop by more than this to count as an improvement."""


def _offsets(counts: torch.Tensor) -> torch.Tensor:
    """``[0, c0, c0 + c1, ...]``: where each segment of a packed table starts, and the end."""
    return torch.cat([counts.new_zeros(1), torch.cumsum(counts, 0)])


@dataclasses.dataclass(frozen=True, eq=False)
class PackedGraphs:
    """Graphs packed into flat tensors: their batch as one block-diagonal graph, unpadded.

    Graph ``g`` owns nodes ``node_ptr[g]:node_ptr[g+1]`` (its whole image first) and
    entries ``edge_ptr[g]:edge_ptr[g+1]`` of the normalised adjacency ``Â`` (self-loops
    included), held as coordinates ``rows``/``cols`` and ``values``, sorted by row then
    column: the order of a coalesced sparse tensor, kept by :meth:`take`, so no batch
    is ever sorted again.
    """

    x: torch.Tensor
    weights: torch.Tensor
    node_ptr: torch.Tensor
    edge_ptr: torch.Tensor
    rows: torch.Tensor
    cols: torch.Tensor
    values: torch.Tensor
    first_layer: torch.Tensor | None = None
    """What a model's first layer reads, per node, if computed once for training (:meth:`GCN.prepare`)."""

    @classmethod
    def of(cls, graphs: Sequence[SceneGraph]) -> PackedGraphs:
        if not graphs:
            raise ValueError("PackedGraphs.of: no graphs")
        dims = {g.features.shape[1] for g in graphs}
        if len(dims) > 1:
            raise ValueError(f"PackedGraphs.of: graphs with different feature sizes {sorted(dims)}")
        node_ptr = np.concatenate([[0], np.cumsum([g.num_nodes for g in graphs])]).astype(np.int64)
        n = int(node_ptr[-1])
        pairs = np.concatenate([g.edges.reshape(-1, 2).astype(np.int64) + start for g, start in zip(graphs, node_ptr)])
        loops = np.arange(n, dtype=np.int64)
        # Both directions and the self-loops, sorted by (row, col), repeated edges merged
        # (sorting and comparing neighbours: np.unique hashes first, 20x slower here).
        key = np.sort(np.concatenate([pairs[:, 0] * n + pairs[:, 1], pairs[:, 1] * n + pairs[:, 0], loops * n + loops]))
        key = key[np.concatenate([[True], key[1:] != key[:-1]])]
        rows, cols = key // n, key % n
        degree = np.bincount(rows, minlength=n).astype(np.float64)
        values = (1.0 / np.sqrt(degree[rows] * degree[cols])).astype(np.float32)
        return cls(
            x=torch.from_numpy(np.concatenate([g.features for g in graphs]).astype(np.float32)),
            weights=torch.from_numpy(np.concatenate([g.weights for g in graphs]).astype(np.float32)),
            node_ptr=torch.from_numpy(node_ptr),
            edge_ptr=torch.from_numpy(np.searchsorted(rows, node_ptr).astype(np.int64)),
            rows=torch.from_numpy(rows),
            cols=torch.from_numpy(cols),
            values=torch.from_numpy(values),
        )

    def __len__(self) -> int:
        return len(self.node_ptr) - 1

    def take(self, index: torch.Tensor | np.ndarray | Sequence[int]) -> PackedGraphs:
        """The graphs ``index`` (in that order) packed alone: a mini-batch, without a Python loop."""
        index = torch.as_tensor(index, dtype=torch.int64)
        start, size = self.node_ptr[index], self.node_ptr[index + 1] - self.node_ptr[index]
        estart, esize = self.edge_ptr[index], self.edge_ptr[index + 1] - self.edge_ptr[index]
        node_ptr, edge_ptr = _offsets(size), _offsets(esize)
        moved = node_ptr[:-1] - start  # how far each graph's node numbers move
        nodes = torch.arange(int(node_ptr[-1])) - torch.repeat_interleave(moved, size)
        edges = torch.arange(int(edge_ptr[-1])) - torch.repeat_interleave(edge_ptr[:-1] - estart, esize)
        shift = torch.repeat_interleave(moved, esize)
        return PackedGraphs(
            self.x[nodes],
            self.weights[nodes],
            node_ptr,
            edge_ptr,
            self.rows[edges] + shift,
            self.cols[edges] + shift,
            self.values[edges],
            self.first_layer[nodes] if self.first_layer is not None else None,
        )

    @property
    def num_nodes(self) -> int:
        return int(self.node_ptr[-1])

    @property
    def whole_image(self) -> torch.Tensor:
        """Index of each graph's whole-image node."""
        return self.node_ptr[:-1]

    @cached_property
    def graph_of_node(self) -> torch.Tensor:
        return torch.repeat_interleave(torch.arange(len(self)), self.node_ptr[1:] - self.node_ptr[:-1])

    @cached_property
    def is_part(self) -> torch.Tensor:
        part = torch.ones(self.num_nodes, dtype=torch.bool)
        part[self.whole_image] = False
        return part

    @property
    def has_parts(self) -> torch.Tensor:
        return (self.node_ptr[1:] - self.node_ptr[:-1] > 1).float()

    @cached_property
    def adjacency(self) -> torch.Tensor:
        """``Â`` as a sparse ``(nodes, nodes)`` tensor (already coalesced by construction)."""
        n = self.num_nodes
        return torch.sparse_coo_tensor(
            torch.stack([self.rows, self.cols]), self.values, (n, n), is_coalesced=True, check_invariants=False
        )

    def pooling(self, *node_weights: torch.Tensor) -> torch.Tensor:
        """Sparse averaging matrix ``(len(node_weights) * graphs, nodes)``: block ``r`` averages
        each graph's nodes by ``node_weights[r]`` (a graph whose weights are all 0 gets a row of zeros)."""
        rows, values = [], []
        for r, w in enumerate(node_weights):
            total = torch.zeros(len(self)).index_add_(0, self.graph_of_node, w)
            rows.append(self.graph_of_node + r * len(self))
            values.append(w / total.clamp(min=1e-12)[self.graph_of_node])
        index = torch.stack([torch.cat(rows), torch.arange(self.num_nodes).repeat(len(node_weights))])
        shape = (len(node_weights) * len(self), self.num_nodes)
        return torch.sparse_coo_tensor(index, torch.cat(values), shape, is_coalesced=True, check_invariants=False)


class CosineHead(nn.Module):
    """Class logits ``scale * cos(state, prototype_c)``: one learned prototype per class."""

    def __init__(self, dim: int, num_classes: int) -> None:
        super().__init__()
        self.prototypes = nn.Parameter(torch.randn(num_classes, dim) * 0.01)
        self.scale = nn.Parameter(torch.tensor(COSINE_SCALE))

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        return self.scale * F.normalize(state, dim=1) @ F.normalize(self.prototypes, dim=1).T


class GCN(nn.Module):
    """Graph classifier: input standardisation, ``layers`` graph convolutions, a readout, a linear output
    (see the module docstring for why each is as it is)."""

    def __init__(
        self,
        in_dim: int,
        num_classes: int,
        hidden: int = 256,
        layers: int = 2,
        dropout: float = 0.0,
        readout: str = "image+parts",
        node_weights: str = "input",
        head: str = "linear",
    ) -> None:
        super().__init__()
        if readout not in READOUTS:
            raise ValueError(f"GCN readout must be one of {', '.join(READOUTS)}; got {readout!r}")
        if node_weights not in NODE_WEIGHTS:
            raise ValueError(f"GCN node_weights must be one of {', '.join(NODE_WEIGHTS)}; got {node_weights!r}")
        if head not in HEADS:
            raise ValueError(f"GCN head must be one of {', '.join(HEADS)}; got {head!r}")
        self.hparams = {
            "in_dim": in_dim, "num_classes": num_classes, "hidden": hidden, "layers": layers,
            "dropout": dropout, "readout": readout, "node_weights": node_weights, "head": head,
        }  # fmt: skip
        # Row 0: whole-image nodes; row 1: parts.
        self.register_buffer("feature_mean", torch.zeros(2, in_dim))
        self.register_buffer("feature_scale", torch.ones(2, in_dim))
        self.convs = nn.ModuleList(nn.Linear(2 * (in_dim if i == 0 else hidden), hidden) for i in range(layers))
        self.dropout = nn.Dropout(dropout)
        pooled_dim = hidden * (2 if readout == "image+parts" else 1)
        self.classifier = nn.Linear(pooled_dim, num_classes) if head == "linear" else CosineHead(pooled_dim, num_classes)

    @torch.no_grad()
    def fit_inputs(self, graphs: PackedGraphs) -> None:
        """Fit the feature statistics on the training graphs (parts borrow the whole images' if there are none)."""
        for role, nodes in enumerate((~graphs.is_part, graphs.is_part)):
            x = graphs.x[nodes] if nodes.any() else graphs.x[~graphs.is_part]
            scale = x.std(dim=0, unbiased=False)
            floor = SCALE_FLOOR * scale.mean()
            self.feature_mean[role] = x.mean(dim=0)
            self.feature_scale[role] = scale.clamp(min=float(floor)) if floor > 0 else torch.ones_like(scale)

    def inputs(self, graphs: PackedGraphs) -> torch.Tensor:
        """The node features standardised (and scaled by the node weights, for ``node_weights="input"``)."""
        role = graphs.is_part.long()
        h = (graphs.x - self.feature_mean[role]) / self.feature_scale[role]
        return h * graphs.weights[:, None] if self.hparams["node_weights"] == "input" else h

    @torch.no_grad()
    def prepare(self, graphs: PackedGraphs) -> PackedGraphs:
        """``graphs`` with what the first layer reads computed once: it does not change while
        training (the statistics are fitted before, and no dropout acts on the inputs)."""
        return dataclasses.replace(graphs, first_layer=self._neighbourhood(self.inputs(graphs), graphs))

    def forward(self, graphs: PackedGraphs) -> torch.Tensor:
        """Class logits ``(graphs, classes)``."""
        return self.classifier(self.dropout(self.pooled(graphs)))

    @torch.no_grad()
    def start_prototypes(self, graphs: PackedGraphs, labels: torch.Tensor) -> None:
        """The cosine head's prototypes: each class's mean pooled state over ``graphs`` (a class
        without a graph keeps its random start)."""
        assert isinstance(self.classifier, CosineHead)
        self.eval()
        pooled = self.pooled(graphs)
        sums = torch.zeros_like(self.classifier.prototypes).index_add_(0, labels, pooled)
        counts = torch.bincount(labels, minlength=len(sums))
        seen = counts > 0
        self.classifier.prototypes[seen] = sums[seen] / counts[seen, None]

    def pooled(self, graphs: PackedGraphs) -> torch.Tensor:
        """The readout's state of each graph, what the head classifies."""
        z = graphs.first_layer if graphs.first_layer is not None else self._neighbourhood(self.inputs(graphs), graphs)
        *inner, last = self.convs
        # The last layer runs on pooled rows, one or two per graph, not on every node:
        # pooling S is linear, so S [H, ÂH] W = [SH, (SÂ)H] W, and only the ReLU moves
        # after the pooling (exact for the whole-image row, which S merely selects). That
        # layer was most of an epoch's arithmetic.
        pool = self._pool(graphs)
        if not inner:
            z = torch.sparse.mm(pool, z)
        for i, conv in enumerate(inner):
            h = self.dropout(torch.relu(conv(z)))
            z = self._neighbourhood(h, graphs, pool if i == len(inner) - 1 else None)
        pooled = torch.relu(last(z))
        if self.hparams["readout"] == "image+parts":
            image, parts = pooled.chunk(2)
            pooled = torch.cat([image, parts * graphs.has_parts[:, None]], dim=1)  # zeros: no parts to summarise
        return pooled

    @staticmethod
    def _neighbourhood(h: torch.Tensor, graphs: PackedGraphs, pool: torch.Tensor | None = None) -> torch.Tensor:
        """``[H, ÂH]``, each node's state beside its neighbourhood's; given a pooling ``S``, its
        pooled rows ``[SH, (SÂ)H]``, where ``SÂ`` is a product of two sparse matrices, so
        ``ÂH`` is never formed for every node."""
        if pool is None:
            return torch.cat([h, torch.sparse.mm(graphs.adjacency, h)], dim=1)
        with warnings.catch_warnings():  # torch multiplies two sparse matrices through its CSR support, "in beta"
            warnings.filterwarnings("ignore", "Sparse CSR tensor support is in beta", UserWarning)
            pool_adjacency = torch.sparse.mm(pool, graphs.adjacency)
        return torch.cat([torch.sparse.mm(pool, h), torch.sparse.mm(pool_adjacency, h)], dim=1)

    def _pool(self, graphs: PackedGraphs) -> torch.Tensor:
        """The readout's averaging matrix: one row per graph, or for ``"image+parts"`` the
        whole-image rows then the parts' rows."""
        kind = self.hparams["readout"]
        if kind == "mean":
            return graphs.pooling(torch.ones(graphs.num_nodes))
        if kind == "weighted":
            return graphs.pooling(graphs.weights)
        return graphs.pooling((~graphs.is_part).float(), graphs.weights * graphs.is_part)

    @torch.no_grad()
    def predict(self, graphs: Sequence[SceneGraph], batch_size: int = 1024) -> np.ndarray:
        """Class probabilities ``(len(graphs), num_classes)``."""
        self.eval()
        if not graphs:
            return np.zeros((0, self.hparams["num_classes"]), np.float32)
        packed = PackedGraphs.of(graphs)
        chunks = torch.arange(len(packed)).split(batch_size)
        return torch.cat([torch.softmax(self(packed.take(c)), dim=-1) for c in chunks]).numpy()


@dataclasses.dataclass(frozen=True)
class TrainingReport:
    """How training went (written to each variant's ``training.json``)."""

    epochs: int
    best_epoch: int
    train_loss: list[float]
    val_loss: list[float]
    """Empty when no class had a graph (or group) to spare for validation."""
    stopped_at_cap: bool
    """Training ran all ``epochs`` without early stopping: it may not have converged."""
    train_accuracy: float
    """Of the returned (best) model on the graphs it trained on, in evaluation mode."""
    val_accuracy: float | None


def validation_split(
    labels: np.ndarray, fraction: float, rng: np.random.Generator, groups: np.ndarray | None = None
) -> np.ndarray:
    """Indices held out for early stopping: about ``fraction`` of each class's graphs, whole groups at a time.

    Graphs of one group (say the jittered copies of one pose) are held out together or
    not at all, so no near-copy of a validation graph is trained on. Groups are drawn in
    random order, and one is held out only if every class in it stays within its share,
    ``round(fraction * n)`` but never its last graph: a class whose graphs all form one
    group (every class of a variant without S) keeps them, and trains without validation.
    Without ``groups`` every graph is its own group.
    """
    labels = np.asarray(labels)
    groups = np.arange(len(labels)) if groups is None else np.asarray(groups)
    classes, counts = np.unique(labels, return_counts=True)
    quota = dict(zip(classes.tolist(), np.minimum(np.round(fraction * counts).astype(int), counts - 1).tolist()))
    _, group_of = np.unique(groups, return_inverse=True)
    by_group = np.split(np.argsort(group_of, kind="stable"), np.cumsum(np.bincount(group_of))[:-1])
    held: list[int] = []
    for g in rng.permutation(len(by_group)):
        members = by_group[g]
        need = Counter(labels[members].tolist())
        if all(k <= quota[c] for c, k in need.items()):
            for c, k in need.items():
                quota[c] -= k
            held.extend(members.tolist())
    return np.array(sorted(held), dtype=np.int64)


def train_gcn(
    graphs: Sequence[SceneGraph],
    labels: np.ndarray,
    num_classes: int,
    config: TrainingConfig,
    progress: Callable[[int, int], None] | None = None,
    groups: np.ndarray | Sequence[int] | None = None,
) -> tuple[GCN, TrainingReport]:
    """Train a GCN on labelled graphs with Adam, early stopping on a held-out share of them.

    Args:
        groups: one int per graph; graphs of a group are held out for validation together
            (pass one group per pose, so jittered copies never straddle the split).
        progress: called with ``(epoch, config.epochs)`` after each epoch.

    Without a validation share (see :func:`validation_split`) the training loss is
    monitored instead. The model of the best epoch is returned.
    """
    labels = np.asarray(labels, dtype=np.int64)
    if len(labels) != len(graphs) or (groups is not None and len(groups) != len(graphs)):
        raise ValueError(
            f"train_gcn: {len(graphs)} graphs, {len(labels)} labels, {len(groups) if groups is not None else '-'} groups"
        )
    with torch_threads(config.threads):
        torch.manual_seed(torch_seed(config.seed, "classifier"))
        val = validation_split(labels, config.validation_fraction, stream(config.seed, "classifier"), groups)
        train = np.setdiff1d(np.arange(len(graphs)), val)
        packed = PackedGraphs.of(graphs)
        train_set, val_set = packed.take(train), (packed.take(val) if len(val) else None)
        y = torch.from_numpy(labels)
        y_train, y_val = y[train], y[val]
        model = GCN(
            packed.x.shape[1], num_classes, config.hidden, config.layers, config.dropout, config.readout, config.node_weights, config.head
        )
        model.fit_inputs(train_set)
        train_set, val_set = model.prepare(train_set), (model.prepare(val_set) if val_set is not None else None)
        if config.head == "cosine":
            model.start_prototypes(train_set, y_train)
        optimiser = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        best, best_epoch, best_state = float("inf"), 0, _snapshot(model)
        train_loss: list[float] = []
        val_loss: list[float] = []
        stopped_at_cap = True
        for epoch in range(1, config.epochs + 1):
            model.train()
            total = 0.0
            for idx in torch.randperm(len(train)).split(config.batch_size):
                loss = F.cross_entropy(model(train_set.take(idx)), y_train[idx])
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
                total += loss.item() * len(idx)
            train_loss.append(total / len(train))
            if val_set is not None:
                val_loss.append(_evaluate(model, val_set, y_val)[0])
            monitored = val_loss[-1] if val_loss else train_loss[-1]
            if monitored < best - MIN_IMPROVEMENT:
                best, best_epoch = monitored, epoch
                best_state = _snapshot(model)
            if progress is not None:
                progress(epoch, config.epochs)
            if epoch - best_epoch >= config.patience:
                stopped_at_cap = False
                break
        model.load_state_dict(best_state)
        report = TrainingReport(
            epochs=len(train_loss),
            best_epoch=best_epoch,
            train_loss=train_loss,
            val_loss=val_loss,
            stopped_at_cap=stopped_at_cap,
            train_accuracy=_evaluate(model, train_set, y_train)[1],
            val_accuracy=_evaluate(model, val_set, y_val)[1] if val_set is not None else None,
        )
    model.eval()
    return model, report


def _snapshot(model: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in model.state_dict().items()}


@torch.no_grad()
def _evaluate(model: GCN, graphs: PackedGraphs, labels: torch.Tensor) -> tuple[float, float]:
    """Loss and accuracy in evaluation mode."""
    model.eval()
    logits = model(graphs)
    return float(F.cross_entropy(logits, labels)), float((logits.argmax(dim=1) == labels).float().mean())


def save_gcn(model: GCN, path: str | Path) -> None:
    """Save ``{"format", "hparams", "state_dict"}`` atomically (the state includes the input statistics)."""
    buffer = io.BytesIO()
    torch.save({"format": CHECKPOINT_FORMAT, "hparams": model.hparams, "state_dict": model.state_dict()}, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def load_gcn(path: str | Path) -> GCN:
    """Load a checkpoint written by :func:`save_gcn` (weights only, strict)."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
            found = ckpt.get("format", 1) if isinstance(ckpt, dict) else type(ckpt).__name__
            raise ValueError(f"checkpoint format {found}, this ssga reads format {CHECKPOINT_FORMAT}; train the variant again")
        model = GCN(**ckpt["hparams"])
        model.load_state_dict(ckpt["state_dict"], strict=True)
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such GCN checkpoint") from None
    except Exception as exc:  # noqa: BLE001 - whatever torch raises, the file is not a usable checkpoint
        detail = " ".join(str(exc).split())[:300]
        raise CheckpointError(f"{path}: not a GCN checkpoint written by ssga ({type(exc).__name__}: {detail})") from None
    model.eval()
    return model
