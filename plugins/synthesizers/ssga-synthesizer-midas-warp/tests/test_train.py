"""The training command: a tiny run, interrupted and resumed, whose export the synthesizer loads with its calibration."""

from __future__ import annotations

import json

import numpy as np
import torch
from ssga_bench.testing import interrupt_training
from ssga_core.testing import make_view
from ssga_synthesizer_midas_warp import train
from ssga_synthesizer_midas_warp.homes import Views
from ssga_synthesizer_midas_warp.plugin import MidasWarp, MidasWarpConfig


def ramps(seed: int, count: int, *, progress=None, size: int = 64) -> Views:
    """Stand-in for rendered homes: brightness falls with depth along a random direction (a learnable cue)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size] / (size - 1)
    depth, rgb = [], []
    for _ in range(count):
        a = rng.uniform(-1, 1, 2)
        z = 1.0 + 3.0 * np.clip(0.5 + a[0] * (xx - 0.5) + a[1] * (yy - 0.5), 0, 1)
        depth.append(z.astype(np.float32))
        rgb.append(np.repeat((255 / z)[..., None], 3, axis=2).astype(np.uint8))
    return Views(np.stack(rgb), np.stack(depth), np.zeros((count, 3)), np.full(count, seed, dtype=np.int64))


def test_a_tiny_run_resumes_after_an_interruption_and_exports_calibrated_weights(tmp_path, monkeypatch):
    monkeypatch.setattr("ssga_synthesizer_midas_warp.homes.render_views", ramps)
    config = train.TrainConfig(
        train_seeds=(2000,), views_per_home=6, stages=((32, 4, 2), (64, 2, 2)), lr=(1e-3, 1e-4),
        calibration_seeds=(2100,), calibration_views=4, checkpoint_every=2,
    )
    first = lambda: train.run_training(config, tmp_path / "run", tmp_path / "out", evaluate_heldout=False, argv=[])  # noqa: E731
    state = interrupt_training(monkeypatch, train.Run, first, tmp_path / "run")
    assert (state["stage"], state["step"], len(state["history"])) == (0, 2, 2)  # the last checkpoint
    path = train.run_training(config, tmp_path / "run", tmp_path / "out", evaluate_heldout=False, argv=["--out", "run"])
    history = torch.load(tmp_path / "run" / "state.pt", weights_only=True)["history"]
    assert [(int(h[0]), int(h[1])) for h in history] == [(0, 1), (0, 2), (0, 3), (0, 4), (1, 1), (1, 2)]
    record = json.loads(path.with_suffix(".json").read_text())
    assert record["command"] == "python -m ssga_synthesizer_midas_warp.train --out run" and record["bytes"] == path.stat().st_size
    assert [s["size"] for s in record["figures"]["loss"]] == [32, 64] and "calibration" in record["figures"]
    calibration = json.loads(path.with_name("midas-light.calibration.json").read_text())
    assert calibration["weights_sha256"] == record["sha256"]
    synthesizer = MidasWarp(MidasWarpConfig(weights=str(path), device="cpu"))
    depth = synthesizer.estimate_depth([make_view(size=64).rgb])
    assert depth.shape == (1, 64, 64) and np.isfinite(depth).all() and (depth > 0).all()
