"""The training command's pieces: labels, batches, the metrics, and a tiny run that is interrupted and resumed."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from ssga_bench.testing import interrupt_training
from ssga_core.testing import make_view
from ssga_parser_cascade_seg import train
from ssga_parser_cascade_seg.classes import PROCEDURAL
from ssga_parser_cascade_seg.evaluate import confusion, scores
from ssga_parser_cascade_seg.homes import HELDOUT_SEEDS, TRAIN_SEEDS, Labelled, class_labels
from ssga_parser_cascade_seg.plugin import FILES, CascadeSeg, CascadeSegConfig

from ssga_core import InputError

BENCHMARK_SEEDS = {0, 1, 2}
OTHER_PLUGINS_SEEDS = set(range(1000, 1008)) | {1100, 1101} | set(range(2000, 2012)) | set(range(2100, 2104)) | set(range(2200, 2204)) | set(range(3000, 3006))


def test_training_and_heldout_homes_are_disjoint_from_the_benchmarks_and_other_plugins():
    train_seeds, held = set(TRAIN_SEEDS), set(HELDOUT_SEEDS)
    assert not (train_seeds & held or (train_seeds | held) & (BENCHMARK_SEEDS | OTHER_PLUGINS_SEEDS))


def test_the_vocabulary_is_the_procedural_categories():
    categories = pytest.importorskip("ssga_workspace_procedural.categories").CATEGORIES
    assert tuple(sorted(categories, key=categories.__getitem__)) == PROCEDURAL
    assert [categories[name] for name in PROCEDURAL] == list(range(1, 14))
    np.testing.assert_array_equal(class_labels(np.array([[-1, 0, 1, 13]], dtype=np.int32)), [[-1, -1, 0, 12]])


def test_metrics_count_as_csails_eval():
    truth = np.array([[0, 0, 1, 1], [2, 2, -1, -1]])
    pred = np.array([[0, 1, 1, 1], [2, 0, 0, 0]])
    counts = confusion(pred, truth, 4)
    assert counts.sum() == 6 and counts[0, 0] == 1 and counts[0, 1] == 1 and counts[2, 0] == 1
    result = scores(counts, ["a", "b", "c", "d"])
    # a: 1 / (2 + 2 - 1); b: 2 / (2 + 3 - 2); c: 1 / 2; d never occurs.
    assert result["iou"] == {"a": round(1 / 3, 4), "b": round(2 / 3, 4), "c": 0.5, "d": None}
    assert result["mean_iou"] == round((1 / 3 + 2 / 3 + 0.5) / 3, 4) and result["pixel_accuracy"] == round(4 / 6, 4)


def test_a_batch_is_cropped_rescaled_and_normalised():
    rng = np.random.default_rng(0)
    data = Labelled(rng.integers(0, 256, (3, 32, 32, 3), dtype=np.uint8), rng.integers(-1, 13, (3, 32, 32)).astype(np.int8), np.zeros(3, dtype=np.int64))
    x, y = train._batch(data, np.random.default_rng(1), 2, 16, (0.5, 0.5), 0.0)
    assert x.shape == (2, 3, 16, 16) and y.shape == (2, 16, 16) and y.dtype == torch.int64
    assert set(np.unique(y.numpy())) <= set(range(-1, 13))
    # The same generator gives the same batch (resumed runs see the batches an uninterrupted one would).
    again = train._batch(data, np.random.default_rng(1), 2, 16, (0.5, 0.5), 0.0)
    assert torch.equal(x, again[0]) and torch.equal(y, again[1])
    _, small = train._batch(data, np.random.default_rng(2), 1, 24, (0.5, 0.5), 0.0)
    assert (small[0, 16:, :] == -1).all() and (small[0, :, 16:] == -1).all(), "what a smaller view does not cover is unknown"


def painted_walls(seed: int, count: int, *, progress=None) -> Labelled:
    """Stand-in for rendered homes (the real renders are the packaged weights' test): make_view's rectangles as classes."""
    views = [make_view(seed=seed + i, size=48) for i in range(count)]
    labels = np.stack([v.semantic for v in views]).astype(np.int8)  # rectangle k is class k (0..11), the wall unknown
    return Labelled(np.stack([v.rgb for v in views]), labels, np.full(count, seed, dtype=np.int64))


def test_a_tiny_run_resumes_after_an_interruption_and_exports_loadable_weights(tmp_path, monkeypatch):
    pytest.importorskip("ssga_workspace_procedural")  # the vocabulary check reads its categories
    monkeypatch.setattr("ssga_parser_cascade_seg.homes.render_labelled", painted_walls)
    config = train.TrainConfig(train_seeds=(TRAIN_SEEDS[0],), views_per_home=4, stages=((32, 4, 2),), lr=(1e-3,), checkpoint_every=2)
    first = lambda: train.run_training(config, tmp_path / "run", tmp_path / "out", evaluate_heldout=False, argv=[])  # noqa: E731
    state = interrupt_training(monkeypatch, train.Run, first, tmp_path / "run")
    assert (state["stage"], state["step"], len(state["history"])) == (0, 2, 2)  # the last checkpoint
    calls = []
    monkeypatch.setattr("ssga_parser_cascade_seg.homes.render_labelled", lambda *a, **k: calls.append(a))  # the views come from the cache
    folder = train.run_training(config, tmp_path / "run", tmp_path / "out", evaluate_heldout=False, argv=["--out", "run"])
    assert calls == []
    history = torch.load(tmp_path / "run" / "state.pt", weights_only=True)["history"]
    assert [int(h[1]) for h in history] == [1, 2, 3, 4]
    provenance = json.loads((folder / "provenance.json").read_text())
    assert provenance["command"] == "python -m ssga_parser_cascade_seg.train --out run" and provenance["classes"] == list(PROCEDURAL)
    for name in FILES.values():
        checkpoint = torch.load(folder / name, weights_only=True)
        assert checkpoint["provenance"]["config"]["stages"] == [[32, 4, 2]] and checkpoint["network"] == "light"
        assert provenance["files"][name]["bytes"] == (folder / name).stat().st_size
    regions = CascadeSeg(CascadeSegConfig(weights=str(folder), device="cpu")).parse(make_view(size=64))
    assert len(regions) > 0 and set(regions.names) <= set(PROCEDURAL)
    with pytest.raises(InputError, match="holds a run of another config"):
        train.Run(train.TrainConfig(), tmp_path / "run")


def test_piece_reliability_counts_a_piece_right_by_its_pixels_majority_and_keeps_it_by_its_score():
    from ssga_parser_cascade_seg.evaluate import piece_reliability

    # One 8 x 8 view: the left half is truly class 0, the right half class 1 with a column of class 2 in it.
    truth = np.zeros((1, 8, 8), np.int8)
    truth[0, :, 4:] = 1
    truth[0, :, 7] = 2
    # The network: the left half class 0 at 0.9 (right), the right half class 2 at 0.4 (its majority is 1: wrong).
    probs = np.full((3, 8, 8), 0.05, np.float32)
    probs[0, :, :4], probs[2, :, 4:] = 0.9, 0.4
    data = Labelled(np.zeros((1, 8, 8, 3), np.uint8), truth, np.array([0]))
    figures = piece_reliability(lambda rgb: probs, data, ("a", "b", "c"), [0.5, 0.3], min_px=1)
    assert figures["all"] == {"pieces": 2, "right": 0.5, "at 0.5": {"kept": 0.5, "right": 1.0}, "at 0.3": {"kept": 1.0, "right": 0.5}}
    assert figures["classes"]["a"] == {"pieces": 1, "right": 1.0, "at 0.5": {"kept": 1.0, "right": 1.0}, "at 0.3": {"kept": 1.0, "right": 1.0}}
    assert figures["classes"]["c"]["at 0.5"] == {"kept": 0.0, "right": None} and "b" not in figures["classes"]
