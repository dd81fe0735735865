"""The GCN place classifier: packing, input statistics, readout, learning, early stopping, checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from ssga_bench.config import TrainingConfig
from ssga_bench.gcn import GCN, PackedGraphs, load_gcn, save_gcn, train_gcn, validation_split
from ssga_core.geometry import Camera
from ssga_core.graph import assemble

from ssga_core import CheckpointError, SceneGraph

FAST = {"hidden": 32, "seed": 0}


def bow_like(
    rng: np.random.Generator, rows: int, common: np.ndarray, pattern: np.ndarray | float = 0.0, noise: float = 0.3
) -> np.ndarray:
    """L2-normalised non-negative histograms that share most of their length in ``common``, as bag-of-words features do."""
    x = np.abs(common + pattern + noise * rng.standard_normal((rows, len(common))))
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


def scene_graphs(n_per_class: int, classes: int, seed: int, parts: tuple[int, int] = (3, 9), noisy_parts: bool = False):
    """Graphs of whole image + parts whose features carry a class pattern under noise;
    ``noisy_parts``: only the whole image does, the parts are noise alike for every class."""
    rng = np.random.default_rng(0)
    common, patterns = rng.random(16) * 3, rng.random((classes, 16))
    rng = np.random.default_rng(seed)
    graphs, labels = [], []
    for c in range(classes):
        for _ in range(n_per_class):
            k = int(rng.integers(*parts))
            corner = rng.uniform(0, 200, (k, 2))
            whole = bow_like(rng, 1, common, patterns[c], noise=0.2 if noisy_parts else 0.3)
            rest = bow_like(rng, k, common, 0.0, noise=0.6) if noisy_parts else bow_like(rng, k, common, patterns[c])
            graphs.append(assemble(Camera(), np.concatenate([corner, corner + 40], axis=1), np.concatenate([whole, rest])))
            labels.append(c)
    return graphs, np.array(labels)


def accuracy(model: GCN, graphs: list[SceneGraph], labels: np.ndarray) -> float:
    return float((model.predict(graphs).argmax(axis=1) == labels).mean())


def test_adjacency_is_symmetrically_normalised_with_self_loops():
    g = SceneGraph(
        boxes=np.zeros((3, 4), np.float32), features=np.ones((3, 2), np.float32),
        weights=np.array([1, 0.5, 0.5], np.float32), edges=np.array([[0, 1], [0, 2], [0, 2]]),  # a repeated edge counts once
    )  # fmt: skip
    deg = np.array([3, 2, 2])  # with self-loops
    expected = np.array([[1, 1, 1], [1, 1, 0], [1, 0, 1]]) / np.sqrt(np.outer(deg, deg))
    np.testing.assert_allclose(PackedGraphs.of([g]).adjacency.to_dense().numpy(), expected, rtol=1e-6)


def test_a_taken_batch_is_the_same_as_packing_those_graphs_alone():
    graphs, _ = scene_graphs(2, 3, seed=0)
    batch, alone = PackedGraphs.of(graphs).take([4, 0, 5]), PackedGraphs.of([graphs[4], graphs[0], graphs[5]])
    for name in ("x", "weights", "node_ptr", "edge_ptr"):
        torch.testing.assert_close(getattr(batch, name), getattr(alone, name))
    torch.testing.assert_close(batch.adjacency.to_dense(), alone.adjacency.to_dense())
    assert batch.whole_image.tolist() == [0, graphs[4].num_nodes, graphs[4].num_nodes + graphs[0].num_nodes]


def test_scores_of_a_graph_do_not_depend_on_its_batch_mates():
    graphs, labels = scene_graphs(3, 3, seed=1)
    model, _ = train_gcn(graphs, labels, 3, TrainingConfig(epochs=3, **FAST))
    together = model.predict(graphs, batch_size=4)
    np.testing.assert_allclose(np.concatenate([model.predict([g]) for g in graphs]), together, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("layers", [1, 2, 3])
def test_first_layer_inputs_computed_once_give_the_same_logits(layers):
    graphs, _ = scene_graphs(2, 3, seed=1)
    packed = PackedGraphs.of(graphs)
    model = GCN(16, 3, hidden=8, layers=layers)
    model.fit_inputs(packed)
    model.eval()
    prepared = model.prepare(packed).take([3, 1])
    torch.testing.assert_close(model(prepared), model(packed.take([3, 1])))


def test_input_statistics_are_fitted_per_node_role():
    graphs, _ = scene_graphs(3, 2, seed=2)
    model = GCN(16, 2)
    model.fit_inputs(PackedGraphs.of(graphs))
    whole = np.stack([g.features[0] for g in graphs])
    parts = np.concatenate([g.features[1:] for g in graphs])
    np.testing.assert_allclose(model.feature_mean.numpy(), [whole.mean(0), parts.mean(0)], rtol=1e-5)
    np.testing.assert_allclose(model.feature_scale[1].numpy(), parts.std(0), rtol=1e-4)
    inputs = model.inputs(PackedGraphs.of(graphs))
    parts_in = inputs[PackedGraphs.of(graphs).is_part] / torch.cat([torch.from_numpy(g.weights[1:]) for g in graphs])[:, None]
    np.testing.assert_allclose(parts_in.mean(0).numpy(), 0, atol=1e-5)  # centred before the node weights scale them


def test_parts_without_a_scale_borrow_a_floor_and_graphs_without_parts_borrow_the_whole_images_statistics():
    graphs = [assemble(Camera(), np.zeros((0, 4)), np.array([[1.0, 0.0]], np.float32) * (i + 1)) for i in range(3)]
    model = GCN(2, 2)
    model.fit_inputs(PackedGraphs.of(graphs))
    torch.testing.assert_close(model.feature_mean[1], model.feature_mean[0])  # no parts: the whole images' statistics
    assert model.feature_scale[0, 1] > 0  # a constant feature is not divided by zero


@pytest.mark.parametrize(
    ("readout", "node_weights", "expected"),
    [
        ("mean", "readout", 1 / 3),  # the whole image is one node of three
        ("weighted", "readout", 1 / 2),  # it weighs as much as both parts together
        ("image+parts", "readout", 1.0),  # its own state, beside the parts' (0)
        ("image+parts", "input", 1.0),
    ],
)
def test_readouts(readout, node_weights, expected):
    g = SceneGraph(
        boxes=np.zeros((3, 4), np.float32), features=np.array([[1.0], [0.0], [0.0]], np.float32),
        weights=np.array([1, 0.5, 0.5], np.float32), edges=np.zeros((0, 2), np.int64),
    )  # fmt: skip
    model = GCN(1, 1, hidden=1, layers=1, readout=readout, node_weights=node_weights)
    with torch.no_grad():  # identity statistics, each node's own state only, sum of the pooled features
        model.convs[0].weight.copy_(torch.tensor([[1.0, 0.0]]))
        model.convs[0].bias.zero_()
        model.classifier.weight.fill_(1.0)
        model.classifier.bias.zero_()
    assert model(PackedGraphs.of([g])).item() == pytest.approx(expected)
    with pytest.raises(ValueError, match="readout"):
        GCN(1, 1, readout="max")


def test_a_graph_without_parts_has_a_zero_parts_summary():
    alone = assemble(Camera(), np.zeros((0, 4)), np.ones((1, 1), np.float32))
    model = GCN(1, 1, hidden=1, layers=1)
    with torch.no_grad():
        model.convs[0].bias.fill_(5.0)  # the summary of no parts would be ReLU(5) without the mask
        model.classifier.weight.copy_(torch.tensor([[0.0, 1.0]]))
        model.classifier.bias.zero_()
    assert model(PackedGraphs.of([alone])).item() == 0.0


def test_learns_separable_classes_and_generalises():
    graphs, labels = scene_graphs(12, 4, seed=1)
    model, report = train_gcn(graphs, labels, 4, TrainingConfig(**FAST))
    test_graphs, test_labels = scene_graphs(6, 4, seed=3)  # same patterns, new noise
    assert accuracy(model, test_graphs, test_labels) > 0.9
    assert report.val_loss and report.best_epoch <= report.epochs and report.train_accuracy > 0.9


def test_whole_image_signal_is_learned_among_many_noisy_parts():
    """The paper's weighting problem: 30 parts of noise beside one informative whole image.
    The image+parts readout keeps the whole image's state; a mean over all nodes at equal
    weights leaves it 1/31 of the pooled state, and it drowns."""
    graphs, labels = scene_graphs(10, 6, seed=4, parts=(28, 33), noisy_parts=True)
    test_graphs, test_labels = scene_graphs(5, 6, seed=5, parts=(28, 33), noisy_parts=True)
    model, report = train_gcn(graphs, labels, 6, TrainingConfig(batch_size=16, **FAST))
    assert report.train_accuracy > 0.95 and accuracy(model, test_graphs, test_labels) > 0.9
    drowned, _ = train_gcn(graphs, labels, 6, TrainingConfig(batch_size=16, readout="mean", node_weights="readout", **FAST))
    assert accuracy(drowned, test_graphs, test_labels) < 0.6


def test_validation_split_never_takes_a_class_s_last_graph():
    labels = np.array([0, 0, 0, 0, 0, 1, 2, 2])
    held = validation_split(labels, 0.4, np.random.default_rng(0))
    assert sorted(labels[held].tolist()) == [0, 0, 2]


def test_groups_never_straddle_the_split():
    labels = np.repeat(np.arange(10), 12)
    groups = np.repeat(np.arange(40), 3)  # four poses per class, three jittered copies of each
    for seed in range(20):
        held = set(validation_split(labels, 0.3, np.random.default_rng(seed), groups).tolist())
        for g in np.unique(groups):
            members = set(np.flatnonzero(groups == g).tolist())
            assert members <= held or not members & held
        kept = np.setdiff1d(np.arange(len(labels)), list(held))
        assert set(labels[kept].tolist()) == set(range(10))  # every class keeps graphs to train on
        assert len(held) == 30  # one group of three per class: a second would pass its share, round(0.3 * 12) = 4


def test_a_class_that_is_one_group_trains_without_validation():
    graphs, labels = scene_graphs(3, 3, seed=6)
    _, report = train_gcn(graphs, labels, 3, TrainingConfig(epochs=5, **FAST), groups=labels)
    assert report.val_loss == [] and report.val_accuracy is None
    with pytest.raises(ValueError, match="groups"):
        train_gcn(graphs, labels, 3, TrainingConfig(epochs=5, **FAST), groups=labels[:-1])


def test_stopped_at_cap_says_whether_early_stopping_ended_training():
    graphs, labels = scene_graphs(6, 3, seed=7)
    _, capped = train_gcn(graphs, labels, 3, TrainingConfig(epochs=3, patience=50, **FAST))
    assert capped.stopped_at_cap and capped.epochs == 3
    _, converged = train_gcn(graphs, labels, 3, TrainingConfig(epochs=2000, patience=5, **FAST))
    assert not converged.stopped_at_cap and converged.epochs == converged.best_epoch + 5 < 2000


def test_training_is_seeded():
    graphs, labels = scene_graphs(3, 3, seed=2)
    config = TrainingConfig(epochs=5, **FAST)
    a, _ = train_gcn(graphs, labels, 3, config)
    b, _ = train_gcn(graphs, labels, 3, config)
    np.testing.assert_array_equal(a.predict(graphs), b.predict(graphs))


def test_training_leaves_torchs_thread_count_as_it_was():
    graphs, labels = scene_graphs(2, 2, seed=2)
    before = torch.get_num_threads()
    train_gcn(graphs, labels, 2, TrainingConfig(epochs=1, threads=1, **FAST))
    assert torch.get_num_threads() == before


def test_checkpoints_round_trip_with_their_input_statistics(tmp_path):
    graphs, labels = scene_graphs(3, 3, seed=3)
    model, _ = train_gcn(graphs, labels, 3, TrainingConfig(epochs=3, **FAST))
    save_gcn(model, tmp_path / "gcn.pt")
    loaded = load_gcn(tmp_path / "gcn.pt")
    torch.testing.assert_close(loaded.feature_mean, model.feature_mean)
    torch.testing.assert_close(loaded.feature_scale, model.feature_scale)
    assert model.feature_scale.abs().sum() > 0 and not torch.equal(model.feature_mean, torch.zeros_like(model.feature_mean))
    np.testing.assert_allclose(loaded.predict(graphs), model.predict(graphs), rtol=1e-6)


def test_bad_checkpoints_are_reported_in_one_line(tmp_path):
    graphs, labels = scene_graphs(2, 3, seed=3)
    model, _ = train_gcn(graphs, labels, 3, TrainingConfig(epochs=1, **FAST))
    save_gcn(model, tmp_path / "gcn.pt")
    state = torch.load(tmp_path / "gcn.pt", weights_only=True)

    def refused(name: str, match: str) -> None:
        with pytest.raises(CheckpointError, match=match) as error:
            load_gcn(tmp_path / name)
        assert "\n" not in str(error.value)

    (tmp_path / "bad.pt").write_bytes(b"garbage")
    refused("bad.pt", "bad.pt: not a GCN checkpoint written by ssga")
    torch.save(
        {**state, "state_dict": {k: v for k, v in state["state_dict"].items() if k != "feature_scale"}}, tmp_path / "missing.pt"
    )
    refused("missing.pt", "Missing key.*feature_scale")
    torch.save({"hparams": state["hparams"], "state_dict": state["state_dict"]}, tmp_path / "old.pt")  # format 1 had no "format"
    refused("old.pt", "format 1, this ssga reads format 2")
    refused("none.pt", "no such GCN checkpoint")


def test_the_cosine_head_starts_each_prototype_at_its_class_mean_and_learns():
    graphs, labels = scene_graphs(12, 4, seed=1)
    model = GCN(16, 5, hidden=32, head="cosine")  # class 4 has no graph: it keeps its random start
    packed = PackedGraphs.of(graphs)
    model.fit_inputs(packed)
    before = model.classifier.prototypes.detach().clone()
    model.start_prototypes(packed, torch.from_numpy(labels))
    pooled = model.pooled(packed).detach()
    for c in range(4):
        torch.testing.assert_close(model.classifier.prototypes[c], pooled[labels == c].mean(dim=0))
    torch.testing.assert_close(model.classifier.prototypes[4], before[4])
    # Untrained, the prototypes already rank each training graph's class first more often than not.
    assert (model(packed).argmax(dim=1).numpy() == labels).mean() > 0.5

    trained, _ = train_gcn(graphs, labels, 4, TrainingConfig(head="cosine", **FAST))
    test_graphs, test_labels = scene_graphs(6, 4, seed=3)
    assert accuracy(trained, test_graphs, test_labels) > 0.9


def test_cosine_checkpoints_round_trip_and_older_ones_load_as_linear(tmp_path):
    graphs, labels = scene_graphs(3, 3, seed=3)
    model, _ = train_gcn(graphs, labels, 3, TrainingConfig(epochs=3, head="cosine", **FAST))
    save_gcn(model, tmp_path / "gcn.pt")
    loaded = load_gcn(tmp_path / "gcn.pt")
    assert loaded.hparams["head"] == "cosine"
    np.testing.assert_allclose(loaded.predict(graphs), model.predict(graphs), rtol=1e-6)
    # A checkpoint written before heads existed has no "head": it is the paper's linear head.
    linear, _ = train_gcn(graphs, labels, 3, TrainingConfig(epochs=1, **FAST))
    save_gcn(linear, tmp_path / "linear.pt")
    state = torch.load(tmp_path / "linear.pt", weights_only=True)
    torch.save({**state, "hparams": {k: v for k, v in state["hparams"].items() if k != "head"}}, tmp_path / "older.pt")
    np.testing.assert_allclose(load_gcn(tmp_path / "older.pt").predict(graphs), linear.predict(graphs), rtol=1e-6)
