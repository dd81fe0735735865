"""The training command's pieces: mirrored moves, the SSIM loss, and a tiny run that is interrupted and resumed."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from ssga_bench.testing import interrupt_training
from ssga_core.testing import make_view
from ssga_synthesizer_synsin import train
from ssga_synthesizer_synsin.model import SynSinLight, render
from ssga_synthesizer_synsin.pairs import Pairs, orbit_poses
from ssga_synthesizer_synsin.plugin import SynSinConfig, SynSinSynthesizer

from ssga_core import InputError, Pose


def fake_pairs(seed: int, count: int, size: int = 64, **_) -> Pairs:
    """Pairs of make_view walls (true depth 3 m) at orbit poses: no workspace needed."""
    rng = np.random.default_rng(seed)
    poses = orbit_poses(lambda x, y: True, (-2.0, -2.0, 2.0, 2.0), count, rng)
    views = [[make_view(seed=int(rng.integers(100)), size=size, pose=Pose(*p)) for p in pair] for pair in poses]
    return Pairs(
        rgb=np.stack([[v.rgb for v in pair] for pair in views]),
        depth=np.stack([[v.depth for v in pair] for pair in views]).astype(np.float16),
        poses=poses,
        home=np.full(count, seed),
    )


def test_orbit_poses_look_at_one_point_from_free_floor():
    rng = np.random.default_rng(0)
    free = lambda x, y: x > 0
    poses = orbit_poses(free, (-5.0, -5.0, 5.0, 5.0), 50, rng, distance_m=(1.0, 1.0), max_turn_deg=40.0)
    assert (poses[..., 0] > 0).all()
    turn = np.degrees(np.abs((poses[:, 1, 2] - poses[:, 0, 2] + np.pi) % (2 * np.pi) - np.pi))
    assert turn.max() <= 40.0 and turn.max() > 20.0
    ahead = poses[..., :2] + np.stack([np.cos(poses[..., 2]), np.sin(poses[..., 2])], -1)  # 1 m ahead of each camera
    np.testing.assert_allclose(ahead[:, 0], ahead[:, 1], atol=1e-9)


def test_a_mirrored_batch_renders_the_mirrored_image():
    """Mirroring both images left-right and the move with them (T' = M T M) mirrors the rendering."""
    data = fake_pairs(1, 4)
    batch = train.batch_tensors(data, train._moves(data), np.random.default_rng(0), 4)
    net = SynSinLight().eval()  # an untrained network renders the splatted colours, which mirror exactly
    K = train.intrinsics(64)
    with torch.no_grad():
        out, _, _ = render(net, batch["source"], K, batch["T"], depth=batch["source_depth"])
        mirrored, _, _ = render(
            net, batch["source"].flip(-1), K, train.MIRROR @ batch["T"] @ train.MIRROR, depth=batch["source_depth"].flip(-1)
        )
        wrong, _, _ = render(net, batch["source"].flip(-1), K, batch["T"], depth=batch["source_depth"].flip(-1))
    assert (mirrored.flip(-1) - out).abs().mean() < 1e-3
    assert (wrong.flip(-1) - out).abs().mean() > 20 * (mirrored.flip(-1) - out).abs().mean()


def test_ssim_is_one_for_equal_images_and_falls_with_noise():
    torch.manual_seed(0)
    x = torch.rand(2, 3, 32, 32) * 2 - 1
    assert float(train.ssim(x, x)) == pytest.approx(1.0)
    assert float(train.ssim(x, x + 0.3 * torch.randn_like(x))) < 0.8


def test_a_tiny_run_resumes_after_an_interruption_and_exports_loadable_weights(tmp_path, monkeypatch):
    config = train.TrainConfig(
        train_seeds=(3000,), pairs_per_home=6, stages=((32, 4, 2), (64, 2, 1)), lr=(1e-3, 1e-4), checkpoint_every=2
    )
    monkeypatch.setattr(train, "render_pairs", fake_pairs)
    first = lambda: train.run_training(config, tmp_path / "run", tmp_path / "out", evaluate_heldout=False, argv=[])  # noqa: E731
    state = interrupt_training(monkeypatch, train.Run, first, tmp_path / "run")
    assert (state["stage"], state["step"], len(state["history"])) == (0, 2, 2)  # the last checkpoint
    monkeypatch.setattr(train, "render_pairs", lambda *a, **k: pytest.fail("the pairs come from the cache"))
    path = train.run_training(config, tmp_path / "run", tmp_path / "out", evaluate_heldout=False, argv=["--out", "run"])
    checkpoint = torch.load(path, weights_only=True)
    provenance = checkpoint["provenance"]
    assert provenance["command"] == "python -m ssga_synthesizer_synsin.train --out run"
    assert [s[1] for s in provenance["config"]["stages"]] == [4, 2] and provenance["train_seeds"] == [3000]
    history = torch.load(tmp_path / "run" / "state.pt", weights_only=True)["history"]
    assert [(int(h[0]), int(h[1])) for h in history] == [(0, 1), (0, 2), (0, 3), (0, 4), (1, 1), (1, 2)]
    assert all(np.isfinite(h[2:]).all() for h in history)
    view = make_view(size=64)
    syn = SynSinSynthesizer(SynSinConfig(weights=str(path), device="cpu")).synthesize(view, Pose(0.1, 0.0, 0.1))
    assert syn.view.rgb.shape == (64, 64, 3)
    with pytest.raises(InputError, match="holds a run of another config"):
        train.Run(train.TrainConfig(), tmp_path / "run")
