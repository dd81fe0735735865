"""The GCN place classifier: it learns, stops early, and round-trips through checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ssga_core import CheckpointError, SceneGraph
from ssga_bench.config import TrainingConfig
from ssga_bench.gcn import GraphBatch, load_gcn, save_gcn, train_gcn, validation_split
from ssga_core.geometry import Camera
from ssga_core.graph import assemble


def toy_graphs(n_per_class: int, classes: int, seed: int) -> tuple[list[SceneGraph], np.ndarray]:
    """Graphs whose part features carry a class-specific pattern under noise."""
    rng = np.random.default_rng(seed)
    patterns = rng.random((classes, 16)).astype(np.float32)
    graphs, labels = [], []
    for c in range(classes):
        for _ in range(n_per_class):
            k = int(rng.integers(3, 9))
            corner = rng.uniform(0, 200, (k, 2))
            feats = patterns[c] + 0.3 * rng.standard_normal((k + 1, 16)).astype(np.float32)
            graphs.append(assemble(Camera(), np.concatenate([corner, corner + 40], axis=1), feats))
            labels.append(c)
    return graphs, np.array(labels)


def test_adjacency_is_symmetrically_normalised_with_self_loops():
    g = SceneGraph(
        boxes=np.zeros((3, 4), np.float32), features=np.ones((3, 2), np.float32),
        weights=np.array([1, 0.5, 0.5], np.float32), edges=np.array([[0, 1], [0, 2]]),
    )
    batch = GraphBatch.of([g])
    deg = np.array([3, 2, 2])  # with self-loops
    a = np.array([[1, 1, 1], [1, 1, 0], [1, 0, 1]]) / np.sqrt(np.outer(deg, deg))
    np.testing.assert_allclose(batch.adj[0].numpy(), a, rtol=1e-6)
    np.testing.assert_allclose(batch.x[0, :, 0].numpy(), [1, 0.5, 0.5])  # features times node weights


def test_padding_is_masked():
    graphs, _ = toy_graphs(1, 2, seed=0)
    batch = GraphBatch.of(graphs)
    sizes = [g.num_nodes for g in graphs]
    assert batch.mask.sum(dim=1).tolist() == sizes


def test_validation_split_never_takes_a_class_s_last_graph():
    labels = np.array([0, 0, 0, 0, 0, 1, 2, 2])
    held = validation_split(labels, 0.4, np.random.default_rng(0))
    assert sorted(labels[held].tolist()) == [0, 0, 2]


def test_learns_separable_classes_and_generalises():
    graphs, labels = toy_graphs(12, 4, seed=1)
    model, report = train_gcn(graphs, labels, 4, TrainingConfig(epochs=80, patience=15, hidden=64, seed=0))
    test_graphs, test_labels = toy_graphs(6, 4, seed=1)  # same patterns, new noise
    accuracy = (model.predict(test_graphs[: len(test_labels)]).argmax(axis=1) == test_labels).mean()
    assert accuracy > 0.9
    assert report.val_loss and report.best_epoch <= report.epochs


def test_training_is_seeded():
    graphs, labels = toy_graphs(3, 3, seed=2)
    config = TrainingConfig(epochs=5, hidden=32)
    a, _ = train_gcn(graphs, labels, 3, config)
    b, _ = train_gcn(graphs, labels, 3, config)
    np.testing.assert_array_equal(a.predict(graphs), b.predict(graphs))


def test_checkpoints_round_trip_and_bad_ones_are_reported(tmp_path):
    graphs, labels = toy_graphs(2, 3, seed=3)
    model, _ = train_gcn(graphs, labels, 3, TrainingConfig(epochs=3, hidden=16))
    save_gcn(model, tmp_path / "gcn.pt")
    np.testing.assert_allclose(load_gcn(tmp_path / "gcn.pt").predict(graphs), model.predict(graphs), rtol=1e-6)
    (tmp_path / "bad.pt").write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="bad.pt: not a GCN checkpoint written by ssga"):
        load_gcn(tmp_path / "bad.pt")
    state = torch.load(tmp_path / "gcn.pt", weights_only=True)
    state["state_dict"].pop("classifier.bias")
    torch.save(state, tmp_path / "missing.pt")
    with pytest.raises(CheckpointError, match="Missing key"):
        load_gcn(tmp_path / "missing.pt")
    with pytest.raises(CheckpointError, match="no such GCN checkpoint"):
        load_gcn(tmp_path / "none.pt")


def test_weighted_readout_pools_by_node_weight():
    import torch

    from ssga_bench.gcn import GCN

    g = SceneGraph(
        boxes=np.zeros((3, 4), np.float32), features=np.array([[1.0], [0.0], [0.0]], np.float32),
        weights=np.array([1, 0.5, 0.5], np.float32), edges=np.zeros((0, 2), np.int64),
    )
    batch = GraphBatch.of([g])
    for readout, share in (("mean", 1 / 3), ("weighted", 1 / 2)):
        model = GCN(1, 1, hidden=1, layers=1, dropout=0.0, readout=readout)
        with torch.no_grad():
            model.convs[0].weight.fill_(1.0)
            model.convs[0].bias.zero_()
            model.classifier.weight.fill_(1.0)
            model.classifier.bias.zero_()
        # Without edges each node keeps its own state: only the whole image's is 1.
        assert model(batch).item() == pytest.approx(share)
    with pytest.raises(ValueError, match="readout"):
        GCN(1, 1, readout="max")
