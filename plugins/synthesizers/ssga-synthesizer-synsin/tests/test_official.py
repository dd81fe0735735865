"""Loading SynSin's released checkpoint layout (``mp3d/synsin.pth``), from a file built here the same way, by the file alone.

SynSin saves ``{'state_dict', 'optimizerG', 'epoch', ['optimizerD'], 'opts'}`` (``train.py``),
with every key under ``model.module.`` (``BaseModel`` around ``nn.DataParallel``), the
VGG19 of its perceptual loss under ``model.module.loss_function.``, the discriminator
under ``netD.``, its options as a pickled ``argparse.Namespace``, and every convolution
and noise-layer linear spectrally normalised (``weight_orig``, ``weight_u``,
``weight_v``). The test file is made by applying ``torch.nn.utils.spectral_norm`` (the
function SynSin calls) to this package's :class:`SynSin`, exactly so; the loaded network
must compute what the spectrally normalised one computes in eval mode.
"""

from __future__ import annotations

import argparse
import copy
import pickle
import warnings

import pytest
import torch
from ssga_core.testing import make_view
from ssga_bench.testing import RunsCode, one_line_checkpoint_error
from ssga_synthesizer_synsin.official import DROPPED_PREFIXES, Splat, SynSin, official_state_dict, spectral_weight
from ssga_synthesizer_synsin.plugin import SynSinConfig, SynSinSynthesizer

from ssga_core import CheckpointError

OPTS = argparse.Namespace(
    radius=4.0, pp_pixel=128, tau=1.0, rad_pow=2, min_z=0.5, max_z=10.0, W=256, ngf=64, norm_G="sync:spectral_batch",
    refine_model_type="resnet_256W8UpDown64", accumulation="alphacomposite", normalize_image=True, losses=["1.0_l1", "10.0_content"],
)  # fmt: skip


def _spectral(net: torch.nn.Module) -> torch.nn.Module:
    """``net`` with SynSin's spectral norm on every convolution and linear layer, its u and v converged."""
    net = copy.deepcopy(net)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch.nn.utils.spectral_norm is deprecated in favour of parametrizations
        for module in list(net.modules()):
            if isinstance(module, torch.nn.Conv2d | torch.nn.Linear):
                torch.nn.utils.spectral_norm(module)
                w = module.weight_orig.detach().reshape(module.weight_orig.shape[0], -1)
                u = module.weight_u
                for _ in range(30):  # the power iteration SynSin's training ran
                    v = torch.nn.functional.normalize(w.t() @ u, dim=0)
                    u = torch.nn.functional.normalize(w @ v, dim=0)
                module.weight_u.copy_(u)
                module.weight_v.copy_(v)
    return net.eval()


@pytest.fixture(scope="module")
def official(tmp_path_factory):
    """An official-layout file and the spectrally normalised network it was saved from."""
    torch.manual_seed(3)
    net = SynSin()
    with torch.no_grad():  # stored statistics that are not the defaults, so loading them matters
        for name, buffer in net.named_buffers():
            if name.endswith(("running_mean", "stored_mean")):
                buffer.uniform_(-0.2, 0.2)
            elif name.endswith(("running_var", "stored_var")):
                buffer.uniform_(0.5, 1.5)
    reference = _spectral(net)
    state = {"model.module." + k: v for k, v in reference.state_dict().items()}
    state["model.module.loss_function.losses.1.model.slice1.0.weight"] = torch.randn(64, 3, 3, 3)
    state["model.module.loss_function.losses.1.model.slice1.0.bias"] = torch.randn(64)
    state["netD.netD.model0.0.weight_orig"] = torch.randn(64, 3, 4, 4)
    state["netD.netD.model0.0.weight_u"] = torch.randn(64)
    checkpoint = {
        "state_dict": state,
        "optimizerG": {"state": {}, "param_groups": []},
        "epoch": 12,
        "optimizerD": {},
        "opts": OPTS,
    }
    path = tmp_path_factory.mktemp("mp3d") / "synsin.pth"
    torch.save(checkpoint, path)
    return path, reference, state


def test_the_file_holds_what_synsins_does(official):
    _, _, state = official
    assert any(k.endswith(".weight_orig") for k in state) and any(k.endswith(".weight_v") for k in state)
    assert "model.module.encoder.gblocks.0.ch_a.0.gain.weight_orig" in state
    assert "model.module.pts_regressor.batch_norm8_7.running_var" in state
    assert "model.module.pts_transformer.xyzs" in state and "model.module.discretized_zs" in state
    with pytest.raises(Exception, match="weights_only"):
        torch.load(official[0], weights_only=True)  # the pickled Namespace needs allowing


def test_the_official_layout_loads_strictly_and_computes_what_synsin_does(official):
    path, reference, _ = official
    s = SynSinSynthesizer(SynSinConfig(weights=str(path), device="cpu"))
    net = s.net
    assert (s.options.radius, s.options.points_per_pixel, s.options.min_z, s.options.max_z) == (4.0, 128, 0.5, 10.0)
    img = torch.rand(1, 3, 256, 256) * 2 - 1
    with torch.inference_mode():
        torch.testing.assert_close(net.depth(img), reference.depth(img), rtol=1e-4, atol=1e-4)
        small = img[..., :32, :48]  # the ResNet encoder and decoder are fully convolutional: a small image is enough
        torch.testing.assert_close(net.features(small), reference.features(small), rtol=1e-4, atol=1e-4)
        feats = torch.randn(1, 64, 32, 48)
        splatted = Splat(feats, torch.ones(1, 1, 32, 48), torch.ones(1, 32, 48), torch.ones(1, 32 * 48))
        out = net.refine(splatted)
        torch.testing.assert_close(out, reference.refine(splatted), rtol=1e-4, atol=1e-4)
    assert out.shape == (1, 3, 32, 48) and out.abs().max() <= 1.0  # SynSin's tanh
    syn = s.synthesize(make_view(size=32), make_view(size=32).pose)
    assert syn.visible.all()


def test_mapping_drops_training_modules_and_folds_spectral_norm(official):
    _, reference, state = official
    own = SynSin().state_dict()
    no_counter = {k: v for k, v in state.items() if not k.endswith("num_batches_tracked")}  # files of torch < 0.4.1
    mapped, counts = official_state_dict(no_counter, own)
    assert set(mapped) == set(own)
    assert (
        counts["dropped"] == 4
        and counts["filled"] == 13
        and counts["spectral"] == sum(k.endswith(".weight_orig") and not k.startswith("netD.") for k in state)
    )
    assert not any(k.startswith(("loss_function.", "netD.")) for k in mapped)
    assert DROPPED_PREFIXES == ("model.module.loss_function.", "netD.")
    conv = reference.pts_regressor.conv3
    with torch.no_grad():
        expected = spectral_weight(conv.weight_orig, conv.weight_u, conv.weight_v)
        torch.testing.assert_close(mapped["pts_regressor.conv3.weight"], expected)
        # the folded weight has spectral norm 1; the stored one did not (so the folding changed something)
        assert float(torch.linalg.matrix_norm(expected.reshape(expected.shape[0], -1), ord=2)) == pytest.approx(1.0, rel=1e-2)
        assert abs(float(torch.linalg.matrix_norm(conv.weight_orig.reshape(conv.weight_orig.shape[0], -1), ord=2)) - 1.0) > 0.1


def test_the_official_file_alone_names_its_network(official, tmp_path, monkeypatch):
    """What a user does: weights = the downloaded file, nothing else."""
    path, _, _ = official
    s = SynSinSynthesizer(SynSinConfig(weights=str(path), device="cpu"))
    assert s.config.network == "synsin" and isinstance(s.net, SynSin)
    copy = pickle.loads(pickle.dumps(s))  # a worker process loads its own network, of the same layout
    assert copy.config.network == "synsin" and isinstance(copy.net, SynSin) and copy.net is not s.net
    assert copy.options == s.options
    # The preset names the file only: the file says its network.
    assert SynSinSynthesizer.presets["mp3d"] == {"weights": "mp3d/synsin.pth"}
    (tmp_path / "mp3d").mkdir()
    (tmp_path / "mp3d" / "synsin.pth").symlink_to(path)
    monkeypatch.chdir(tmp_path)
    assert SynSinSynthesizer(SynSinConfig(**SynSinSynthesizer.presets["mp3d"], device="cpu")).config.network == "synsin"


def test_a_network_the_file_contradicts_is_one_line_naming_both(official):
    path, _, _ = official
    message = one_line_checkpoint_error(
        lambda: SynSinSynthesizer(SynSinConfig(weights=str(path), network="light"))  # the official file read as the light network
    )
    assert message.startswith("synthesizer 'synsin': config field network = 'light' contradicts config field 'weights'")
    assert "synsin.pth holds the 'synsin' layout (SynSin's released MP3D model" in message and "leave network out" in message


def test_an_official_file_with_other_keys_names_the_closest_layout(official, tmp_path):
    _, _, state = official
    broken = {k: v for k, v in state.items() if "projector.eblocks.7" not in k}
    broken["model.module.modifier.conv1.weight"] = torch.zeros(1)  # the 'modifier' depth predictor: another architecture
    bad = tmp_path / "other.pth"
    torch.save({"state_dict": broken, "opts": OPTS, "epoch": 1, "optimizerG": {}}, bad)
    message = one_line_checkpoint_error(
        lambda: SynSinSynthesizer(SynSinConfig(weights=str(bad))), "'weights'", "other.pth matches none of the layouts it loads ('light', 'synsin')"
    )
    assert "closest: 'synsin': " in message and "missing: projector.eblocks.7" in message and "1 unexpected: modifier.conv1.weight" in message


def test_a_truncated_official_file_is_one_line(official, tmp_path):
    whole = official[0].read_bytes()
    cut = tmp_path / "synsin.pth"
    cut.write_bytes(whole[: len(whole) // 2])
    with pytest.raises(CheckpointError, match="synsin.pth is not a readable checkpoint") as err:
        SynSinSynthesizer(SynSinConfig(weights=str(cut)))
    assert "\n" not in str(err.value)


def test_allowing_synsins_options_runs_no_code(official, tmp_path):
    """SynSin's argparse.Namespace is allowed in; a file that also carries code is still refused, and the code never runs."""
    ran = tmp_path / "ran"
    path = tmp_path / "synsin.pth"
    torch.save({"state_dict": official[2], "opts": OPTS, "epoch": 1, "optimizerG": RunsCode(f"touch {ran}")}, path)
    with pytest.raises(CheckpointError, match="synsin.pth is not a readable checkpoint") as err:
        SynSinSynthesizer(SynSinConfig(weights=str(path)))
    assert "\n" not in str(err.value) and not ran.exists()
    torch.load(path, weights_only=False)  # the file is live: loaded unsafely, it runs
    assert ran.exists()
