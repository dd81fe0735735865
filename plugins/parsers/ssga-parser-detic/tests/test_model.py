"""The network without weights: its checkpoint layout, strict loading, the classifier and a whole forward pass."""

from __future__ import annotations

import collections

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from ssga_parser_detic.checkpoint import OPTIONAL_KEYS, ZS_WEIGHT_KEYS, load_state
from ssga_parser_detic.model import NORM_TEMP, DeticR50, Settings, detect, init_random
from ssga_parser_detic.plugin import LAYOUTS, DeticConfig

from ssga_core import CheckpointError

# The layout of the released ResNet-50 checkpoint, derived from Detic's config
# (Detic_LCOCOI21k_CLIP_R5021k_640b32_4x_ft4x_max-size -> Base-C2_L_R5021k_640b64_4x) and the
# modules it builds; counted by hand here, independently of the network's code.
EXPECTED_FAMILIES = {
    # build_p67_timm_fpn_backbone -> TIMM(resnet50_in21k).base, FrozenBN (weight, bias, running_mean,
    # running_var): stem conv1 + bn1 = 5; 16 bottlenecks x (3 convs + 3 x 4) = 240; 4 shortcuts x (conv + 4) = 20.
    "backbone.bottom_up.base.": 265,
    # FPN.IN_FEATURES layer3..5 (strides 8, 16, 32), NORM "": 1x1 lateral and 3x3 output convs with biases.
    "backbone.fpn_lateral": 6,
    "backbone.fpn_output": 6,
    # LastLevelP6P7_P5: p6, p7.
    "backbone.top_block.": 4,
    # CenterNet with ONLY_PROPOSAL and WITH_AGN_HM: bbox_tower 4 x (conv + GroupNorm) = 16, bbox_pred 2,
    # scales 5 (p3..p7), agn_hm 2; no cls_logits, no cls or share tower convs.
    "proposal_generator.centernet_head.": 25,
    # 3 cascade stages of FastRCNNConvFCHead (NUM_FC 2): fc1, fc2.
    "roi_heads.box_head.": 12,
    # 3 x (cls_score.linear 2 + bbox_pred.0 2 + bbox_pred.2 2); each stage's zs_weight is in the file, not the network.
    "roi_heads.box_predictor.": 18,
    # MaskRCNNConvUpsampleHead, NUM_CONV 4, CLS_AGNOSTIC_MASK: mask_fcn1..4, deconv, predictor.
    "roi_heads.mask_head.": 12,
}

EXPECTED_SHAPES = {
    "backbone.bottom_up.base.conv1.weight": (64, 3, 7, 7),
    "backbone.bottom_up.base.bn1.running_var": (64,),
    "backbone.bottom_up.base.layer1.0.downsample.0.weight": (256, 64, 1, 1),
    "backbone.bottom_up.base.layer2.0.conv2.weight": (128, 128, 3, 3),
    "backbone.bottom_up.base.layer4.2.conv3.weight": (2048, 512, 1, 1),
    "backbone.bottom_up.base.layer4.0.downsample.1.running_mean": (2048,),
    "backbone.fpn_lateral3.weight": (256, 512, 1, 1),
    "backbone.fpn_lateral5.weight": (256, 2048, 1, 1),
    "backbone.fpn_output4.weight": (256, 256, 3, 3),
    "backbone.top_block.p7.weight": (256, 256, 3, 3),
    "proposal_generator.centernet_head.bbox_tower.0.weight": (256, 256, 3, 3),
    "proposal_generator.centernet_head.bbox_tower.10.bias": (256,),
    "proposal_generator.centernet_head.bbox_pred.weight": (4, 256, 3, 3),
    "proposal_generator.centernet_head.scales.4.scale": (1,),
    "proposal_generator.centernet_head.agn_hm.weight": (1, 256, 3, 3),
    "roi_heads.box_head.0.fc1.weight": (1024, 256 * 7 * 7),
    "roi_heads.box_head.2.fc2.weight": (1024, 1024),
    "roi_heads.box_predictor.1.cls_score.linear.weight": (512, 1024),
    "roi_heads.box_predictor.2.bbox_pred.0.weight": (1024, 1024),
    "roi_heads.box_predictor.2.bbox_pred.2.weight": (4, 1024),
    "roi_heads.mask_head.mask_fcn4.weight": (256, 256, 3, 3),
    "roi_heads.mask_head.deconv.weight": (256, 256, 2, 2),
    "roi_heads.mask_head.predictor.weight": (1, 256, 1, 1),
}

PATH = "detic.pth"
WHO = "parser 'detic'"


def load(net: DeticR50, checkpoint, expected: str = "Detic's R50 layout") -> None:
    """``load_state`` as the parser calls it, with its layouts and a config that sets no field of theirs."""
    load_state(net, checkpoint, WHO, PATH, expected, LAYOUTS, DeticConfig(weights="random"))


@pytest.fixture(scope="module")
def net() -> DeticR50:
    return init_random(DeticR50(), 0).eval()


@pytest.fixture(scope="module")
def released(net) -> dict:
    """A checkpoint as detectron2 saves it: the model (with a 22048-class training vocabulary and the unused
    ImageNet-21k classifier, shortened here) and bookkeeping entries."""
    model = {k: v.clone() for k, v in net.state_dict().items()}
    model.update({key: torch.randn(512, 22048) for key in ZS_WEIGHT_KEYS})
    model.update({"backbone.bottom_up.base.fc.weight": torch.zeros(7, 2048), "backbone.bottom_up.base.fc.bias": torch.zeros(7)})
    return {"model": model, "__author__": "Detic", "matching_heuristics": True, "iteration": 180000}


def test_the_network_has_the_checkpoints_key_families_and_shapes(net):
    state = net.state_dict()
    counts = collections.Counter(next((f for f in EXPECTED_FAMILIES if k.startswith(f)), k) for k in state)
    assert dict(counts) == EXPECTED_FAMILIES
    assert len(state) + len(ZS_WEIGHT_KEYS) == 351
    for key, shape in EXPECTED_SHAPES.items():
        assert tuple(state[key].shape) == shape, key
    assert not any(k.endswith("num_batches_tracked") for k in state), "frozen batch norms keep no counter"


def test_a_detectron2_checkpoint_loads_strictly(net, released):
    fresh = DeticR50()
    load(fresh, released)
    for key, value in net.state_dict().items():
        assert torch.equal(fresh.state_dict()[key], value), key


def _error(net, checkpoint) -> str:
    with pytest.raises(CheckpointError) as caught:
        load(net, checkpoint)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"{WHO}: config field 'weights': {PATH}")
    return message


def _with(released, **changes) -> dict:
    model = dict(released["model"])
    for key, value in changes.items():
        key = key.replace("__", ".")
        if value is None:
            del model[key]
        else:
            model[key] = value
    return {**released, "model": model}


def test_mismatched_checkpoints_are_one_line_errors_naming_the_file(net, released):
    wrong = _error(net, _with(released, roi_heads__box_head__0__fc1__weight=torch.zeros(1024, 100)))
    assert "matches none of the layouts it loads ('resnet50-in21k'); closest: 'resnet50-in21k': " in wrong
    assert "1 wrong shape: roi_heads.box_head.0.fc1.weight (1024, 100) (expected (1024, 12544))" in wrong
    extra = _error(net, _with(released, roi_heads__extra__weight=torch.zeros(3)))
    assert "1 unexpected: roi_heads.extra.weight" in extra
    missing = _error(net, _with(released, backbone__fpn_output3__bias=None))
    assert "1 missing: backbone.fpn_output3.bias" in missing
    no_vocabulary = _error(net, _with(released, roi_heads__box_predictor__1__cls_score__zs_weight=None))
    assert "1 missing: roi_heads.box_predictor.1.cls_score.zs_weight" in no_vocabulary
    bad_vocabulary = _error(net, _with(released, roi_heads__box_predictor__0__cls_score__zs_weight=torch.zeros(256, 10)))
    assert "roi_heads.box_predictor.0.cls_score.zs_weight (256, 10) (expected (512, 10))" in bad_vocabulary
    # An optional key of the wrong shape is not dropped silently.
    odd_fc = _error(net, _with(released, backbone__bottom_up__base__fc__weight=torch.zeros(7, 1000)))
    assert "unexpected: backbone.bottom_up.base.fc.weight" in odd_fc
    assert "no 'model' state dict" in _error(net, {"state_dict": released["model"], "iteration": 3})
    assert "a list, not a dict" in _error(net, [1, 2])


def test_optional_keys_are_accepted_with_or_without(net, released):
    without = {k: v for k, v in released["model"].items() if k not in OPTIONAL_KEYS}
    load(DeticR50(), {"model": without})
    load(DeticR50(), {"model": {**without, "pixel_mean": torch.zeros(3, 1, 1), "pixel_std": torch.ones(3, 1, 1)}})
    load(DeticR50(), without | {k: released["model"][k] for k in ZS_WEIGHT_KEYS})  # a bare state dict


def test_a_file_saved_by_a_newer_detectron2_loads_without_its_frozen_batch_norm_counters(net, released):
    counters = {k.removesuffix("running_mean") + "num_batches_tracked": torch.tensor(0) for k in released["model"] if k.endswith(".running_mean")}
    assert len(counters) > 40  # one per frozen batch norm of the backbone
    fresh = DeticR50()
    load(fresh, _with(released) | {"model": released["model"] | counters})
    for key, value in net.state_dict().items():
        assert torch.equal(fresh.state_dict()[key], value), key
    stray = _error(net, _with(released, roi_heads__box_head__0__fc1__num_batches_tracked=torch.tensor(0)))
    assert "1 unexpected: roi_heads.box_head.0.fc1.num_batches_tracked" in stray  # only a batch norm's counter goes


def test_the_zero_shot_classifier_is_a_scaled_cosine_with_a_zero_background(net):
    embeddings = torch.randn(5, 512) * torch.arange(1, 6)[:, None]  # norms differ: they must not matter
    classifier = net.roi_heads.box_predictor[0].cls_score
    classifier.set_vocabulary(embeddings)
    assert classifier.zs_weight.shape == (512, 6)
    features = torch.randn(4, 1024)
    logits = classifier(features)
    projected = classifier.linear(features)
    cosine = F.cosine_similarity(projected[:, None, :], embeddings[None, :, :], dim=2)
    torch.testing.assert_close(logits[:, :5], NORM_TEMP * cosine, rtol=1e-4, atol=1e-4)
    assert torch.equal(logits[:, 5], torch.zeros(4))


def _image(seed: int = 0, size: int = 256) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rgb = np.full((size, size, 3), rng.integers(0, 256, 3), dtype=np.uint8)
    for _ in range(6):
        x, y = rng.integers(0, size - 40, 2)
        rgb[y : y + rng.integers(20, 120), x : x + rng.integers(20, 120)] = rng.integers(0, 256, 3)
    return rgb


def test_a_forward_pass_gives_well_formed_detections(net):
    classes = 30
    net.set_vocabulary(torch.randn(classes, 512, generator=torch.Generator().manual_seed(0)))  # its own draw: the test does not depend on the tests before it
    rgb = _image()
    # The mask head runs on every detection kept: 40 keep the test fast (Detic's default is 300).
    everything = detect(net, rgb, Settings(size=256, score_threshold=0.0, max_detections=40))
    n = len(everything)
    assert 10 <= n <= 40
    boxes, scores = everything.boxes, everything.scores
    assert boxes.shape == (n, 4) and everything.masks.shape == (n, 256, 256) and everything.masks.dtype == bool
    assert (boxes >= 0).all() and (boxes <= 256).all() and (boxes[:, 2] > boxes[:, 0]).all() and (boxes[:, 3] > boxes[:, 1]).all()
    assert ((scores > 0) & (scores <= 1)).all() and (np.diff(scores) <= 0).all()
    assert ((everything.classes >= 0) & (everything.classes < classes)).all()
    centres = np.arange(256) + 0.5
    for box, mask in zip(boxes, everything.masks, strict=True):
        rows, cols = np.nonzero(mask)
        assert ((centres[cols] >= box[0]) & (centres[cols] <= box[2]) & (centres[rows] >= box[1]) & (centres[rows] <= box[3])).all()
    assert everything.masks.any(axis=(1, 2)).mean() > 0.5, "most detections should have a mask"
    # A higher threshold keeps exactly the detections above it: lower scores never suppress higher ones.
    cut = float(scores[9])
    above = detect(net, rgb, Settings(size=256, score_threshold=cut))
    np.testing.assert_array_equal(above.scores, scores[scores > cut])
    np.testing.assert_array_equal(above.boxes, boxes[scores > cut])
    # Every class of every box, not only its best, gives more detections above the same score.
    assert len(detect(net, rgb, Settings(size=256, score_threshold=cut, one_class_per_proposal=False))) > len(above)


def test_detections_are_in_the_images_own_pixels_whatever_the_network_size(net):
    net.set_vocabulary(torch.randn(10, 512))
    rgb = _image(seed=1, size=200)[:, :160]  # 200 x 160: resized to 256 x 204, and back
    found = detect(net, rgb, Settings(size=256, score_threshold=0.0, max_detections=20))
    assert len(found) and found.masks.shape[1:] == (200, 160)
    assert (found.boxes[:, [0, 2]] <= 160).all() and (found.boxes[:, [1, 3]] <= 200).all()
    assert found.boxes[:, 2].max() > 120 and found.boxes[:, 3].max() > 150, "boxes should span the image, not the 256 x 204 input"
