"""The example learned plugin: registered, trained for a few steps by its command, loaded back, and a descriptor like any other."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from ssga_descriptor_tinyseg import train
from ssga_descriptor_tinyseg.plugin import TinySeg, TinySegConfig

from ssga_bench.testing import interrupt_training
from ssga_core import MissingWeightsError
from ssga_core.testing import check_descriptor, check_descriptor_in_all_orders, make_view

TINY = train.TrainConfig(train_seeds=(9000, 9001), views_per_home=6, stages=((256, 12, 4),), lr=(3e-3,), checkpoint_every=4)


def pixel_accuracy(descriptor: TinySeg, data: train.Labelled) -> float:
    hits = [(descriptor.probabilities(rgb).argmax(-1) == labels)[labels >= 0].mean() for rgb, labels in zip(data.rgb, data.labels, strict=True)]
    return float(np.mean(hits))


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """The training command run as a user runs it, interrupted once and resumed: (weights, run folder)."""
    folder = tmp_path_factory.mktemp("tinyseg")
    command = ["--out", str(folder / "run"), "--export", str(folder), "--no-eval"]
    with pytest.MonkeyPatch.context() as monkeypatch:
        monkeypatch.setattr(train, "TrainConfig", lambda: TINY)
        state = interrupt_training(monkeypatch, train.Run, lambda: train.main(command), folder / "run", after=5)
        assert (state["stage"], state["step"]) == (0, 4), "the last checkpoint before the interruption"
        assert train.main(command) == 0
    return folder / "tinyseg.pt", folder / "run"


def test_is_installed_and_registered(ssga_installed_registry):
    entry = ssga_installed_registry.entry("descriptor", "tinyseg")
    assert entry.cls is TinySeg and entry.plugin.distribution == "ssga-descriptor-tinyseg"


def test_the_trained_network_beats_its_initialisation_on_the_views_it_trained_on(trained):
    weights, run = trained
    history = torch.load(run / "state.pt", weights_only=True)["history"]
    assert [int(h[1]) for h in history] == list(range(1, 13)), "resumed where it stopped, every step once"
    data = train.Labelled.concat([train.Labelled.load(p) for p in sorted((run / "views").glob("labelled-*.npz"))])
    assert len(data) == 12
    before = pixel_accuracy(TinySeg(TinySegConfig(weights="random")), data)
    after = pixel_accuracy(TinySeg(TinySegConfig(weights=str(weights))), data)
    assert after > before + 0.2, (before, after)
    assert torch.load(weights, weights_only=True)["provenance"]["command"].startswith("python -m ssga_descriptor_tinyseg.train --out ")


def test_the_trained_descriptor_meets_the_contract_in_every_order_it_allows(trained):
    descriptor = TinySeg(TinySegConfig(weights=str(trained[0])))
    check_descriptor(descriptor)
    assert {"PD", "PSD", "SPD"} <= set(check_descriptor_in_all_orders(descriptor))
    whole, *parts = descriptor.describe(make_view(), None)
    assert not parts and whole.sum() == pytest.approx(1.0, abs=1e-4), "the whole image's class shares"


def test_missing_weights_are_one_line_naming_the_field(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(MissingWeightsError, match="config field 'weights' = 'tinyseg.pt': no such file"):
        TinySeg()
