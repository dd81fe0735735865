"""The network: the official v2.1-small state-dict layout, MiDaS's preprocessing, strict loading and its errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from ssga_synthesizer_midas_warp.model import LIGHT, V21_SMALL, MidasNet, network_size, predict, preprocess
from ssga_synthesizer_midas_warp.plugin import MidasWarp, MidasWarpConfig

from ssga_bench import checkpoint_bytes
from ssga_core import CheckpointError, MissingWeightsError


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


def test_an_official_style_state_dict_loads_strictly(tmp_path, official):
    """A plain state dict (as the released midas_v21_small_256.pt) and MiDaS's {'model', 'optimizer'} format."""
    state = official.state_dict()
    for name, obj in (("plain.pt", state), ("train-format.pt", {"model": state, "optimizer": {}})):
        synthesizer = MidasWarp(MidasWarpConfig(network="v21-small", weights=_save(tmp_path / name, obj), calibration="minmax", device="cpu"))
        for key in ("pretrained.layer1.0.weight", "scratch.output_conv.4.bias"):
            torch.testing.assert_close(synthesizer.net.state_dict()[key], state[key])


def test_loading_errors_name_the_field_and_the_file(tmp_path, official):
    state = official.state_dict()
    missing = dict(state)
    del missing["scratch.refinenet2.out_conv.bias"]
    cases = {
        "absent.pt": (str(tmp_path / "absent.pt"), MissingWeightsError, "no such file"),
        "missing.pt": (_save(tmp_path / "missing.pt", missing), CheckpointError, "1 missing: scratch.refinenet2.out_conv.bias"),
        "extra.pt": (_save(tmp_path / "extra.pt", {**state, "scratch.extra": torch.zeros(1)}), CheckpointError, "1 unexpected: scratch.extra"),
        "corrupt.pt": (str(tmp_path / "corrupt.pt"), CheckpointError, "not a readable checkpoint"),
        "light.pt": (_save(tmp_path / "light.pt", MidasNet(LIGHT).state_dict()), CheckpointError, "wrong shape"),
    }
    (tmp_path / "corrupt.pt").write_bytes(b"\x80\x02 not a checkpoint" * 10)
    for name, (weights, kind, what) in cases.items():
        message = _error(MidasWarpConfig(network="v21-small", weights=weights, calibration="minmax"), kind)
        assert "config field 'weights'" in message and name in message and what in message, message
        assert "synthesizer 'midas-warp'" in message


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
