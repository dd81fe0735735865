"""The committed light weights and their calibration: provenance, size, and depth better than random weights'."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ssga_synthesizer_midas_warp.calibration import calibration_path, sha256_file
from ssga_synthesizer_midas_warp.evaluate import evaluate_predictions
from ssga_synthesizer_midas_warp.homes import CALIBRATION_SEEDS, HELDOUT_SEEDS, TRAIN_SEEDS
from ssga_synthesizer_midas_warp.plugin import LIGHT_WEIGHTS, WEIGHTS_DIR, MidasWarp, MidasWarpConfig

from ssga_bench.testing import packaged_provenance

WEIGHTS = WEIGHTS_DIR / LIGHT_WEIGHTS
BENCHMARK_SEEDS = {0, 1, 2}


def test_the_weights_carry_their_provenance():
    provenance = packaged_provenance(WEIGHTS, "ssga_synthesizer_midas_warp.train")
    train, cal, held = set(provenance["train_seeds"]), set(provenance["calibration_seeds"]), set(provenance["heldout_seeds"])
    assert train == set(TRAIN_SEEDS) and cal == set(CALIBRATION_SEEDS) and held == set(HELDOUT_SEEDS)
    assert not (train & cal or train & held or cal & held or (train | cal | held) & BENCHMARK_SEEDS)
    assert provenance["figures"]["training_seconds"] <= 25 * 60 * 1.1
    calibration = json.loads(calibration_path(WEIGHTS).read_text())
    assert calibration["weights_sha256"] == sha256_file(WEIGHTS) and calibration["network"] == "light"
    assert calibration["scale"] > 0  # the network predicts inverse depth: nearer is higher
    assert set(calibration["provenance"]["seeds"]) == cal


@pytest.fixture(scope="module")
def rendered():
    """Three RGB-D views of a held-out home (never trained or calibrated on)."""
    pytest.importorskip("ssga_workspace_procedural")
    from ssga_synthesizer_midas_warp.homes import render_views

    return render_views(HELDOUT_SEEDS[1], 3)


def test_trained_depth_beats_random_weights(rendered):
    trained = MidasWarp(MidasWarpConfig(device="cpu"))
    random = MidasWarp(MidasWarpConfig(weights="random", device="cpu"))
    figures = {name: evaluate_predictions(s.predict(rendered.rgb), rendered.depth, s.calibration) for name, s in (("trained", trained), ("random", random))}
    # What the synthesizer uses: the stored calibration (random weights: the min/max prior).
    assert figures["trained"]["calibrated"]["abs_rel"] < 0.8 * figures["random"]["minmax"]["abs_rel"]
    # The relative depth itself, each aligned to the truth per image.
    assert figures["trained"]["aligned"]["abs_rel"] < 0.7 * figures["random"]["aligned"]["abs_rel"]
    assert figures["trained"]["aligned"]["delta1"] > figures["random"]["aligned"]["delta1"] + 0.1
    # And the synthesizer's depth is that calibrated depth.
    depth = trained.estimate_depth(rendered.rgb[:1])[0]
    np.testing.assert_allclose(depth, trained.calibration.depth(trained.predict(rendered.rgb[:1])[0], trained.config.depth_range))
