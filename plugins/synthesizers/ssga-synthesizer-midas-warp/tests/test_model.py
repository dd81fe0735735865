"""The network: the official v2.1-small state-dict layout, MiDaS's preprocessing, the layout a file names, strict loading and its errors."""

from __future__ import annotations


import numpy as np
import pytest
import torch
from ssga_synthesizer_midas_warp.calibration import Calibration, calibration_path, sha256_file
from ssga_synthesizer_midas_warp.model import LIGHT, V21_SMALL, MidasNet, network_size, predict, preprocess
from ssga_synthesizer_midas_warp.plugin import OFFICIAL_WEIGHTS, MidasWarp, MidasWarpConfig

from ssga_bench import checkpoint_bytes
from ssga_core import CheckpointError, MissingWeightsError, resolve_stage


@pytest.fixture(scope="module")
def official() -> MidasNet:
    torch.manual_seed(0)
    return MidasNet(V21_SMALL).eval()


def test_the_official_v21_small_layout(official):
    """482 keys, prefixes pretrained.* (432) and scratch.*, the shapes REFERENCE §2.3 lists, ~21.3M parameters."""
    state = official.state_dict()
    assert len(state) == 482
    assert sum(k.startswith("pretrained.") for k in state) == 432
    assert all(k.startswith(("pretrained.", "scratch.")) for k in state)
    shapes = {
        "pretrained.layer1.0.weight": (32, 3, 3, 3),  # stem
        "pretrained.layer1.1.running_var": (32,),
        "pretrained.layer1.3.0.conv_dw.weight": (32, 1, 3, 3),  # block 0: depthwise-separable
        "pretrained.layer1.4.0.conv_pwl.weight": (32, 144, 1, 1),  # block 1: inverted residual, 24 -> 144 -> 32
        "pretrained.layer1.4.2.conv_pw.weight": (192, 32, 1, 1),
        "pretrained.layer2.0.2.bn3.weight": (48,),
        "pretrained.layer3.1.0.conv_pwl.weight": (136, 576, 1, 1),
        "pretrained.layer3.1.4.conv_pwl.weight": (136, 816, 1, 1),
        "pretrained.layer4.1.0.bn3.weight": (384,),
        "scratch.layer1_rn.weight": (64, 32, 3, 3),
        "scratch.layer4_rn.weight": (512, 384, 3, 3),
        "scratch.refinenet4.resConfUnit2.conv1.weight": (512, 512, 3, 3),
        "scratch.refinenet4.out_conv.weight": (256, 512, 1, 1),
        "scratch.refinenet1.out_conv.weight": (64, 64, 1, 1),
        "scratch.output_conv.0.weight": (32, 64, 3, 3),
        "scratch.output_conv.2.weight": (32, 32, 3, 3),
        "scratch.output_conv.4.weight": (1, 32, 1, 1),
    }
    for key, shape in shapes.items():
        assert tuple(state[key].shape) == shape, key
    assert not any(k.startswith("scratch.layer") and k.endswith("bias") for k in state)  # the stage projections have no bias
    assert 21.0e6 < sum(p.numel() for p in official.parameters()) < 21.5e6


def test_stage_channels_and_strides(official):
    with torch.inference_mode():
        stages = official.pretrained(torch.zeros(1, 3, 128, 192))
    assert [tuple(s.shape[1:]) for s in stages] == [(32, 32, 48), (48, 16, 24), (136, 8, 12), (384, 4, 6)]


def test_the_light_network_is_the_same_family():
    light, official = MidasNet(LIGHT).state_dict(), MidasNet(V21_SMALL).state_dict()
    assert set(light) < set(official)  # the same modules and names, fewer blocks
    assert len(light) == 248
    assert sum(p.numel() for p in MidasNet(LIGHT).parameters()) < 1.5e6  # v2.1-small: 21.3M


@pytest.mark.parametrize(
    ("shape", "expected"),
    [((256, 256), (256, 256)), ((500, 741), (160, 256)), ((480, 640), (192, 256)), ((1000, 300), (256, 64)), ((100, 100), (256, 256)), ((100, 300), (96, 256))],
)
def test_network_size_is_midas_upper_bound(shape, expected):
    assert network_size(*shape, 256) == expected


def test_preprocessing_and_prediction_size():
    rgb = np.full((500, 741, 3), (124, 116, 104), dtype=np.uint8)  # the ImageNet mean, about
    x = preprocess([rgb], 256)
    assert x.shape == (1, 3, 160, 256) and x.abs().max() < 0.05
    torch.manual_seed(0)
    out = predict(MidasNet(LIGHT).eval(), [rgb, rgb])
    assert out.shape == (2, 500, 741) and out.dtype == np.float32


def _save(path, obj) -> str:
    path.write_bytes(checkpoint_bytes(obj))
    return str(path)


def _error(config: MidasWarpConfig, kind=CheckpointError) -> str:
    with pytest.raises(kind) as info:
        MidasWarp(config)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_the_official_file_alone_names_its_network(tmp_path, official):
    """What a user does: weights = the downloaded file, nothing else; plain (as the released
    midas_v21_small_256.pt) or in MiDaS's {'model', 'optimizer'} training format."""
    state = official.state_dict()
    for folder, obj in (("plain", state), ("train-format", {"model": state, "optimizer": {}})):
        (tmp_path / folder).mkdir()
        config = MidasWarpConfig(weights=_save(tmp_path / folder / OFFICIAL_WEIGHTS, obj), calibration="minmax", device="cpu")
        synthesizer = MidasWarp(config)
        assert synthesizer.config.network == "v21-small"
        for key in ("pretrained.layer1.0.weight", "scratch.output_conv.4.bias"):
            torch.testing.assert_close(synthesizer.net.state_dict()[key], state[key])
    again = MidasWarp(config)  # the network cached in this process: the file's network comes with it
    assert again.net is synthesizer.net and again.config.network == "v21-small" and config.network is None
    assert MidasWarp(MidasWarpConfig(device="cpu")).config.network == "light"  # the packaged weights
    assert MidasWarp(MidasWarpConfig(weights="random", device="cpu")).config.network == "light"


def test_the_calibration_is_checked_against_the_files_network(tmp_path, official):
    weights = tmp_path / OFFICIAL_WEIGHTS
    _save(weights, official.state_dict())
    Calibration(0.5, 0.1, "v21-small", sha256_file(weights), {}).write(calibration_path(weights))
    synthesizer = MidasWarp(MidasWarpConfig(weights=str(weights), device="cpu"))  # calibration = 'auto': the file beside it
    assert synthesizer.calibration is not None and synthesizer.calibration.network == "v21-small"


def test_the_preset_names_only_the_file(ssga_installed_registry, tmp_path, monkeypatch, official):
    monkeypatch.chdir(tmp_path)
    stage = resolve_stage("synthesizer", {"name": "midas-warp", "preset": "v21-small", "calibration": "minmax"}, ssga_installed_registry)
    assert stage.config.weights == OFFICIAL_WEIGHTS and stage.config.network is None  # the file says its network
    with pytest.raises(MissingWeightsError, match=f"'weights' = '{OFFICIAL_WEIGHTS}': no such file"):
        stage.create()
    _save(tmp_path / OFFICIAL_WEIGHTS, official.state_dict())
    assert stage.create().config.network == "v21-small"


def test_a_network_the_file_contradicts_is_one_line_naming_both(tmp_path, official):
    weights = _save(tmp_path / OFFICIAL_WEIGHTS, official.state_dict())
    message = _error(MidasWarpConfig(weights=weights, network="light", calibration="minmax"))
    assert "synthesizer 'midas-warp': config field network = 'light' contradicts config field 'weights'" in message
    assert f"{OFFICIAL_WEIGHTS} holds the 'v21-small' layout (the official MiDaS v2.1 small release" in message
    assert "leave network out to take the file's" in message
    light = _save(tmp_path / "light.pt", MidasNet(LIGHT).state_dict())
    message = _error(MidasWarpConfig(weights=light, network="v21-small", calibration="minmax"))
    assert "network = 'v21-small' contradicts" in message and "light.pt holds the 'light' layout" in message


def test_a_file_of_no_known_layout_names_the_closest_and_its_first_differences(tmp_path, official):
    edited = dict(official.state_dict())
    del edited["scratch.refinenet2.out_conv.bias"]
    edited["scratch.extra"] = torch.zeros(1)
    message = _error(MidasWarpConfig(weights=_save(tmp_path / "edited.pt", edited), calibration="minmax"))
    assert "config field 'weights'" in message and "edited.pt matches none of the layouts it loads ('light', 'v21-small')" in message
    assert "closest: 'v21-small': 1 missing: scratch.refinenet2.out_conv.bias; 1 unexpected: scratch.extra" in message
    resnet = {"conv1.weight": torch.zeros(64, 3, 7, 7), "fc.weight": torch.zeros(10, 512)}  # another network altogether
    message = _error(MidasWarpConfig(weights=_save(tmp_path / "resnet.pt", {"state_dict": resnet}), calibration="minmax"))
    assert "matches none of the layouts" in message and "closest: 'light': 248 missing: pretrained.layer1.0.weight" in message
    assert "2 unexpected: conv1.weight, fc.weight" in message


def test_unreadable_files_are_one_line(tmp_path):
    whole = checkpoint_bytes(MidasNet(LIGHT).state_dict())
    (tmp_path / "truncated.pt").write_bytes(whole[: len(whole) // 2])
    (tmp_path / "noise.pt").write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    _save(tmp_path / "no-tensors.pt", {"state_dict": {"pretrained.layer1.0.weight": [1.0, 2.0]}})
    cases = {
        "absent.pt": (MissingWeightsError, "no such file"),
        "truncated.pt": (CheckpointError, "is not a readable checkpoint"),
        "noise.pt": (CheckpointError, "is not a readable checkpoint"),
        "no-tensors.pt": (CheckpointError, "holds no state dict of tensors; expected a MiDaS-small state dict"),
    }
    for name, (kind, what) in cases.items():
        message = _error(MidasWarpConfig(weights=str(tmp_path / name), calibration="minmax"), kind)
        assert message.startswith("synthesizer 'midas-warp': config field 'weights'") and name in message and what in message, message


def test_calibration_errors_name_the_field_and_the_file(tmp_path):
    weights = _save(tmp_path / "w.pt", MidasNet(LIGHT).state_dict())
    message = _error(MidasWarpConfig(weights=weights), MissingWeightsError)  # 'auto': w.calibration.json beside it
    assert "config field 'calibration'" in message and "w.calibration.json" in message and "calibrate" in message
    (tmp_path / "w.calibration.json").write_text("{not json")
    message = _error(MidasWarpConfig(weights=weights))
    assert "config field 'calibration'" in message and "is not a calibration" in message
    # A calibration fitted for other weights is refused.
    packaged = MidasWarp(MidasWarpConfig(device="cpu"))
    assert packaged.calibration is not None
    packaged.calibration.write(tmp_path / "w.calibration.json")
    message = _error(MidasWarpConfig(weights=weights))
    assert "was fitted for" in message and "calibrate these weights" in message
