"""The network in plain torch: CSAIL's key layout and counts (REFERENCE §5), output stride 8, test-time scales, multi-scale averaging."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from ssga_parser_cascade_seg.classes import ADE20K, PROCEDURAL
from ssga_parser_cascade_seg.model import (
    LIGHT,
    NETWORKS,
    RESNET18DILATED,
    RESNET50DILATED,
    SYNC_BN_BUFFERS,
    SceneParser,
    init_weights,
    plain_batch_norm_state,
    predict,
    scale_sizes,
    to_input,
)


def with_sync_bn_buffers(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``state`` as CSAIL's SynchronizedBatchNorm2d saves it: three more buffers per batch norm."""
    out = dict(state)
    for key, value in state.items():
        if key.endswith(".running_mean"):
            owner = key[: -len(".running_mean")]
            out[f"{owner}._tmp_running_mean"] = value.clone()
            out[f"{owner}._tmp_running_var"] = state[f"{owner}.running_var"].clone()
            out[f"{owner}._running_iter"] = torch.ones(1)
    return out


@pytest.fixture(scope="module")
def r50() -> SceneParser:
    return SceneParser(RESNET50DILATED, len(ADE20K)).eval()


def test_the_resnet50_dilated_release_layout_has_reference_key_counts(r50):
    encoder, decoder = r50.encoder.state_dict(), r50.decoder.state_dict()
    # REFERENCE §5: 495 encoder keys built from CSAIL's code, 165 of them the synchronized batch norms' buffers; 58 decoder keys.
    assert len(with_sync_bn_buffers(encoder)) == 495 and len(encoder) == 330
    assert sum(k.endswith(SYNC_BN_BUFFERS) for k in with_sync_bn_buffers(encoder)) == 165
    assert len(with_sync_bn_buffers(decoder)) == 58 and len(decoder) == 40
    # And without num_batches_tracked (torch before 0.4.1): 275 and 34.
    assert len([k for k in encoder if not k.endswith("num_batches_tracked")]) == 275
    assert len([k for k in decoder if not k.endswith("num_batches_tracked")]) == 34


def test_the_key_names_are_csails(r50):
    encoder = r50.encoder.state_dict()
    stem = re.compile(r"^(conv[123]\.weight|bn[123]\.(weight|bias|running_mean|running_var|num_batches_tracked))$")
    layer = re.compile(r"^layer[1-4]\.\d+\.(conv[123]\.weight|bn[123]\.\w+|downsample\.0\.weight|downsample\.1\.\w+)$")
    assert all(stem.match(k) or layer.match(k) for k in encoder), [k for k in encoder if not (stem.match(k) or layer.match(k))]
    assert not any(k.startswith(("fc.", "avgpool")) for k in encoder)
    assert [len({k.split(".")[1] for k in encoder if k.startswith(f"layer{i}.")}) for i in range(1, 5)] == [3, 4, 6, 3]
    assert {k.split(".")[0] + "." + k.split(".")[2] for k in encoder if ".downsample." in k} == {f"layer{i}.downsample" for i in range(1, 5)}
    decoder = r50.decoder.state_dict()
    assert {k.rsplit(".", 1)[0] for k in decoder} == {
        *(f"ppm.{i}.{j}" for i in range(4) for j in (1, 2)),
        "cbr_deepsup.0", "cbr_deepsup.1", "conv_last.0", "conv_last.1", "conv_last.4", "conv_last_deepsup",
    }  # fmt: skip
    shapes = {k: tuple(v.shape) for k, v in decoder.items()}
    assert shapes["ppm.0.1.weight"] == (512, 2048, 1, 1) and shapes["cbr_deepsup.0.weight"] == (512, 1024, 3, 3)
    assert shapes["conv_last.0.weight"] == (512, 2048 + 4 * 512, 3, 3) and shapes["conv_last.4.weight"] == (150, 512, 1, 1)
    assert shapes["conv_last_deepsup.weight"] == (150, 512, 1, 1)


def test_resnet18_dilated_and_the_light_network_share_the_layout():
    r18 = SceneParser(RESNET18DILATED, len(ADE20K))
    light = SceneParser(LIGHT, len(PROCEDURAL))
    assert RESNET18DILATED.fc_dim == 512 and RESNET50DILATED.fc_dim == 2048 and LIGHT.fc_dim == 128
    assert r18.encoder.state_dict().keys() == light.encoder.state_dict().keys()
    assert r18.decoder.state_dict().keys() == light.decoder.state_dict().keys()
    assert len(with_sync_bn_buffers(r18.encoder.state_dict())) == 207  # 23 convolutions, 23 batch norms of 8 keys each
    assert r18.encoder.layer1[0].downsample is not None, "the deep stem gives layer1 128 channels, so even ResNet18's first block projects"


def test_dilations_keep_the_output_stride_at_8():
    net = SceneParser(RESNET50DILATED, 150)
    layer3, layer4 = net.encoder.layer3, net.encoder.layer4
    # The block that strode in a plain ResNet now dilates by half the stage's dilation.
    assert (layer3[0].conv2.stride, layer3[0].conv2.dilation, layer3[1].conv2.dilation) == ((1, 1), (1, 1), (2, 2))
    assert (layer4[0].conv2.stride, layer4[0].conv2.dilation, layer4[2].conv2.dilation) == ((1, 1), (2, 2), (4, 4))
    assert layer4[0].downsample[0].stride == (1, 1) and net.encoder.layer2[0].downsample[0].stride == (2, 2)
    r18 = SceneParser(RESNET18DILATED, 150).encoder
    assert (r18.layer3[0].conv1.dilation, r18.layer3[0].conv2.dilation, r18.layer4[1].conv1.dilation) == ((1, 1), (2, 2), (4, 4))
    light = SceneParser(LIGHT, 13).eval()
    with torch.no_grad():
        features = light.encoder(torch.zeros(1, 3, 96, 64))
        logits, deepsup = light.forward_train(torch.zeros(2, 3, 96, 64))
    assert [tuple(f.shape[1:]) for f in features] == [(16, 24, 16), (32, 12, 8), (64, 12, 8), (128, 12, 8)]
    assert logits.shape == deepsup.shape == (2, 13, 12, 8)


def test_init_is_seeded():
    a, b = (init_weights(SceneParser(LIGHT, 13), 3).state_dict() for _ in range(2))
    c = init_weights(SceneParser(LIGHT, 13), 4).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(a["encoder.conv1.weight"], c["encoder.conv1.weight"])


@pytest.mark.parametrize(
    ("shape", "sizes", "max_size", "expected"),
    [
        ((480, 640), (300, 450), 1000, [(304, 400), (456, 600)]),  # 300 x 400 rounded up to multiples of 8
        ((256, 256), (256,), 1000, [(256, 256)]),  # the benchmark's views pass unchanged
        ((256, 256), (300,), 1000, [(304, 304)]),
        ((100, 1000), (600,), 1000, [(104, 1000)]),  # the longer side caps the scale
        ((257, 255), (256,), 1000, [(264, 256)]),
    ],
)
def test_scale_sizes_follow_csails_test_dataset(shape, sizes, max_size, expected):
    assert scale_sizes(shape, sizes, max_size, 8) == expected


def test_input_is_rgb_over_255_normalised_by_imagenet_statistics():
    rgb = np.zeros((8, 8, 3), dtype=np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 255, 124, 0
    x = to_input(rgb, (8, 8), torch.device("cpu"))
    np.testing.assert_allclose(x[0, :, 0, 0].numpy(), [(1 - 0.485) / 0.229, (124 / 255 - 0.456) / 0.224, -0.406 / 0.225], rtol=1e-5)
    assert to_input(rgb, (16, 12), torch.device("cpu")).shape == (1, 3, 16, 12)


def test_multi_scale_averages_the_softmax_of_each_scale():
    net = init_weights(SceneParser(LIGHT, 13), 0).eval()
    rgb = np.random.default_rng(0).integers(0, 256, (40, 56, 3), dtype=np.uint8)
    single = [predict(net, rgb, (s,)) for s in (32, 48)]
    both = predict(net, rgb, (32, 48))
    assert both.shape == (13, 40, 56)
    torch.testing.assert_close(both, (single[0] + single[1]) / 2)
    torch.testing.assert_close(both.sum(0), torch.ones(40, 56))
    assert not torch.allclose(single[0], single[1], atol=1e-3), "the scales see different inputs"
    with torch.no_grad():
        logits = net(to_input(rgb, (40, 56), torch.device("cpu")))
    upsampled = torch.nn.functional.interpolate(logits, (40, 56), mode="bilinear", align_corners=False).softmax(1)[0]
    torch.testing.assert_close(predict(net, rgb, (40,)), upsampled)


def test_plain_batch_norm_state_drops_only_batch_norm_bookkeeping():
    net = SceneParser(LIGHT, 13)
    state = net.encoder.state_dict()
    plain = {k: v for k, v in state.items() if not k.endswith("num_batches_tracked")}
    for given in (state, plain, with_sync_bn_buffers(state), with_sync_bn_buffers(plain)):
        cleaned = plain_batch_norm_state(given)
        assert cleaned.keys() == state.keys()
        net.encoder.load_state_dict(cleaned, strict=True)
    stray = {**state, "conv1._tmp_running_mean": torch.zeros(16), "layer1.0.bn1.extra": torch.zeros(1)}
    assert set(plain_batch_norm_state(stray)) - set(state) == {"conv1._tmp_running_mean", "layer1.0.bn1.extra"}


def test_every_network_builds():
    for name, layout in NETWORKS.items():
        assert SceneParser(layout, 13).decoder.conv_last[4].out_channels == 13, name
