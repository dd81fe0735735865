"""The training command's pieces: pose relations, WPCA whitening, and a tiny run that is interrupted and resumed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from ssga_bench.testing import interrupt_training
from ssga_core.testing import make_view
from ssga_descriptor_pnv import train
from ssga_descriptor_pnv.homes import relations
from ssga_descriptor_pnv.layout import LIGHT_WIDTHS
from ssga_descriptor_pnv.model import PatchNetVLAD
from ssga_descriptor_pnv.plugin import Pnv, PnvConfig

from ssga_core import InputError


def test_positives_are_near_in_place_and_heading_negatives_far_in_either():
    poses = np.array([[0, 0, 0], [0.5, 0, math.radians(20)], [5, 0, 0], [0, 0, math.pi], [0, 0, 0], [2, 0, 0]], dtype=float)
    homes = np.array([1, 1, 1, 1, 2, 1])
    pos, neg = relations(poses, homes, poses, homes, positive_m=1.0, positive_deg=30, negative_m=3.0, negative_deg=90)
    assert pos[0].tolist() == [True, True, False, False, False, False]
    assert neg[0].tolist() == [False, False, True, True, True, False]  # 2 m, same heading: neither
    assert (pos == pos.T).all() and (neg == neg.T).all() and not (pos & neg).any()


def test_wpca_whitens_the_training_descriptors():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(300, 8 * 16)) @ rng.normal(size=(8 * 16, 8 * 16)) + 3.0
    net = PatchNetVLAD((4, 4, 4, 4, 16), clusters=8, num_pcs=20)
    figures = train.fit_wpca(net, x)
    conv = net.WPCA[0]
    y = x @ conv.weight.detach().double().flatten(1).numpy().T + conv.bias.detach().double().numpy()
    np.testing.assert_allclose(y.mean(0), 0.0, atol=1e-4)
    np.testing.assert_allclose(np.cov(y.T), np.eye(20), atol=1e-3)
    assert 0.0 < figures["explained_variance"] < 1.0
    with pytest.raises(InputError, match="needs more than 20 descriptors"):
        train.fit_wpca(net, x[:20])


def test_a_tiny_run_resumes_after_an_interruption_and_exports_loadable_weights(tmp_path, monkeypatch):
    config = train.TrainConfig(
        train_seeds=(1000,), places_per_home=6, homes_per_batch=1, places_per_batch=4, hard_negatives=2,
        widths=LIGHT_WIDTHS, clusters=4, num_pcs=8, stages=((64, 4),), lr=(1e-4,),
        kmeans_images=6, kmeans_per_image=8, pca_images=12, checkpoint_every=2,
    )
    first = lambda: train.run_training(config, tmp_path / "run", tmp_path / "out", evaluate_heldout=False, argv=[])  # noqa: E731
    state = interrupt_training(monkeypatch, train.Run, first, tmp_path / "run")
    assert (state["stage"], state["step"], len(state["history"])) == (0, 2, 2)  # the last checkpoint
    calls = []
    monkeypatch.setattr(train, "render_places", lambda *a, **k: calls.append(a))  # the views come from the cache
    path = train.run_training(config, tmp_path / "run", tmp_path / "out", evaluate_heldout=False, argv=["--out", "run"])
    assert calls == []
    checkpoint = torch.load(path, weights_only=True)
    assert [h[1] for h in checkpoint["provenance"]["config"]["stages"]] == [4]
    assert checkpoint["provenance"]["command"] == "python -m ssga_descriptor_pnv.train --out run"
    history = torch.load(tmp_path / "run" / "state.pt", weights_only=True)["history"]
    assert [int(h[1]) for h in history] == [1, 2, 3, 4]
    local = Pnv(PnvConfig(weights=str(path), num_pcs=8, device="cpu")).extract(make_view())
    assert local.descriptors.shape == (144, 8) and np.isfinite(local.descriptors).all()
    with pytest.raises(InputError, match="holds a run of another config"):
        train.Run(train.TrainConfig(), tmp_path / "run")
