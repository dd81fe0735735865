"""The cascade-seg parser: registration, contract, regions from a class map, config, release folders and strict loading, device."""

from __future__ import annotations

import dataclasses
import pickle
import re
import shlex

import numpy as np
import pytest
import torch
from pydantic import ValidationError
from ssga_parser_cascade_seg.classes import ADE20K, PROCEDURAL
from ssga_parser_cascade_seg.model import LIGHT, RESNET18DILATED, RESNET50DILATED, SceneParser, init_weights
from ssga_parser_cascade_seg.plugin import FILES, LAYOUTS, LIGHT_WEIGHTS, CascadeSeg, CascadeSegConfig, class_regions

from ssga_bench import checkpoint_bytes, validate_experiment
from ssga_bench.testing import RunsCode
from ssga_core import Camera, CheckpointError, ConfigError, InputError, MissingWeightsError, Pose, Regions, View, resolve_stage
from ssga_core.testing import check_parser, check_parser_in_all_orders, make_view

RANDOM = CascadeSegConfig(weights="random", device="cpu")


def save_release(folder, net: SceneParser, *, sync_bn: bool = False, batches_tracked: bool = True, wrap: dict | None = None):
    """``net`` as a release folder: raw state dicts as CSAIL's train.py saves them (or under our wrapper)."""
    folder.mkdir(parents=True, exist_ok=True)
    for part, module in (("encoder", net.encoder), ("decoder", net.decoder)):
        state = {k: v for k, v in module.state_dict().items() if batches_tracked or not k.endswith("num_batches_tracked")}
        if sync_bn:
            for key in [k for k in state if k.endswith(".running_mean")]:
                owner = key[: -len(".running_mean")]
                state[f"{owner}._tmp_running_mean"] = state[key].clone()
                state[f"{owner}._tmp_running_var"] = state[f"{owner}.running_var"].clone()
                state[f"{owner}._running_iter"] = torch.ones(1)
        obj = state if wrap is None else {**wrap, "state_dict": state}
        (folder / FILES[part]).write_bytes(checkpoint_bytes(obj))
    return folder


def trained_like(seed: int = 1) -> SceneParser:
    """A light network whose batch norms hold non-trivial statistics (so a wrong load shows)."""
    net = init_weights(SceneParser(LIGHT, len(PROCEDURAL)), seed)
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.copy_(torch.rand(m.num_features, generator=generator) * 0.2 - 0.1)
                m.running_var.copy_(torch.rand(m.num_features, generator=generator) + 0.5)
    return net.eval()


def test_is_installed_and_registered(ssga_installed_registry):
    entry = ssga_installed_registry.entry("parser", "cascade-seg")
    assert entry.cls is CascadeSeg and entry.plugin.distribution == "ssga-parser-cascade-seg"
    assert CascadeSeg.tag() == "SE"


def test_meets_the_parser_contract():
    check_parser(CascadeSeg(RANDOM), make_view(seed=1, size=128))
    check_parser(CascadeSeg(RANDOM), make_view(seed=2, size=100))


def test_runs_in_every_order():
    assert "SPD" in check_parser_in_all_orders(CascadeSeg(RANDOM), make_view(seed=3, size=96))


def test_regions_are_the_connected_pieces_of_each_class():
    classes = np.full((12, 16), 2, dtype=np.int32)  # class 2 everywhere...
    classes[1:4, 1:4] = 0  # ...with two pieces of class 0 that touch only at a corner,
    classes[4:6, 4:9] = 0
    classes[8:11, 10:15] = 5  # one of class 5,
    classes[0, 15] = 5  # a one-pixel piece of class 5,
    classes[10:12, 0:2] = -1  # and pixels without a class.
    eight = class_regions(classes, PROCEDURAL, min_px=0, connectivity=8)
    assert eight.categories.tolist() == [0, 2, 5, 5]
    assert eight.names == ("wall", "ceiling", "sofa", "sofa")
    np.testing.assert_array_equal(eight.mask(0), classes == 0)  # corner-touching pieces join with 8 neighbours
    np.testing.assert_array_equal(eight.mask(1), classes == 2)
    assert {eight.mask(2).sum(), eight.mask(3).sum()} == {15, 1}
    assert (eight.labels[classes == -1] == -1).all()
    four = class_regions(classes, PROCEDURAL, min_px=0, connectivity=4)
    assert four.categories.tolist() == [0, 0, 2, 5, 5] and sorted([four.mask(0).sum(), four.mask(1).sum()]) == [9, 10]
    big = class_regions(classes, PROCEDURAL, min_px=11, connectivity=4)
    assert big.categories.tolist() == [2, 5] and (big.labels[classes == 0] == -1).all(), "small pieces are left out, not merged"
    assert np.bincount(big.labels[big.labels >= 0]).min() >= 11
    # Numbering, boxes and categories are the core's.
    core = Regions.from_labels(four.labels, categories=four.categories)
    np.testing.assert_array_equal(core.labels, four.labels)
    np.testing.assert_array_equal(core.boxes, four.boxes)


def test_pieces_larger_than_split_px_are_cut_into_compact_parts_of_their_class():
    classes = np.full((40, 60), 2, dtype=np.int32)  # a large piece of class 2 (1700 px)...
    classes[5:15, 5:15] = 5  # ...around a small one of class 5 (100 px)
    classes[30:, :] = -1
    rgb = np.zeros((40, 60, 3), np.uint8)
    rgb[:, 30:] = 200  # a colour edge through the large piece
    confidence = np.linspace(0.5, 1.0, classes.size, dtype=np.float32).reshape(classes.shape)
    whole = class_regions(classes, PROCEDURAL, 0, 8, confidence)
    cut = class_regions(classes, PROCEDURAL, 0, 8, confidence, rgb, split_px=600)
    large = cut.categories == 2
    # SLIC is asked for ceil(1700 / 600) = 3 and keeps the two halves of one colour: parts, not the piece.
    assert large.sum() >= 2 and (~large).sum() == 1, "the large piece in parts, the small one whole"
    np.testing.assert_array_equal(cut.labels >= 0, whole.labels >= 0)  # every pixel of a piece stays in one of its parts
    np.testing.assert_array_equal(cut.mask(np.flatnonzero(~large)[0]), classes == 5)
    for k in np.flatnonzero(large):
        assert (classes[cut.mask(k)] == 2).all() and cut.names[k] == "ceiling"
        assert cut.mask(k).sum() <= 1200, "none near the whole piece"
        np.testing.assert_allclose(cut.scores[k], confidence[cut.mask(k)].mean(), rtol=1e-5)
    # Each part lies on one side of the colour edge (SLICO follows it).
    assert all(len(np.unique(rgb[cut.mask(k)][:, 0])) == 1 for k in np.flatnonzero(large))
    np.testing.assert_array_equal(cut.boxes, Regions.from_labels(cut.labels).boxes)
    assert class_regions(classes, PROCEDURAL, 0, 8, confidence, rgb, split_px=10_000).labels.tolist() == whole.labels.tolist()


def test_split_px_cuts_the_parsers_regions_and_says_so():
    view = make_view(seed=4, size=128)
    whole, cut = CascadeSeg(RANDOM), CascadeSeg(RANDOM.model_copy(update={"split_px": 500}))
    assert not whole.regions_cut_from_pieces and cut.regions_cut_from_pieces
    assert whole.regions_are_category_pieces and cut.regions_are_category_pieces
    a, b = whole.parse(view), cut.parse(view)
    assert len(b) > len(a) and np.bincount(b.labels[b.labels >= 0]).max() <= 1500
    check_parser(cut, view)
    # Off, the field is left out of cache keys: runs made before it resume.
    assert "split_px" in CascadeSegConfig().unkeyed() and "split_px" not in CascadeSegConfig(split_px=500).unkeyed()


def test_scores_are_the_mean_confidence_of_each_region():
    classes = np.zeros((4, 6), dtype=np.int32)
    classes[:, 3:] = 1
    confidence = np.where(classes == 0, 0.9, 0.4).astype(np.float32)
    confidence[0, 0] = 0.3
    regions = class_regions(classes, PROCEDURAL, 0, 8, confidence)
    np.testing.assert_allclose(regions.scores, [(11 * 0.9 + 0.3) / 12, 0.4], rtol=1e-6)
    assert regions.scores.dtype == np.float32
    assert class_regions(classes, PROCEDURAL, 0).scores is None


def test_parse_gives_class_names_categories_and_scores():
    parser = CascadeSeg(CascadeSegConfig(weights="random", device="cpu", min_region_px=0))
    view = make_view(seed=0, size=128)
    regions = parser.parse(view)
    classes = parser.classify(view.rgb)
    assert len(regions) >= 2
    for k in range(len(regions)):
        assert (classes[regions.mask(k)] == regions.categories[k]).all()
        assert regions.names[k] == PROCEDURAL[regions.categories[k]]
    assert ((regions.labels >= 0) == (classes >= 0)).all(), "with min_region_px = 0 every pixel is in a region"
    assert ((0 < regions.scores) & (regions.scores <= 1)).all()
    probs = parser.probabilities(view.rgb)
    assert probs.shape == (len(PROCEDURAL), 128, 128) and np.allclose(probs.sum(0), 1.0, atol=1e-5)


def test_ignored_classes_get_no_region():
    config = CascadeSegConfig(weights="random", device="cpu", min_region_px=0)
    view = make_view(seed=0, size=128)
    every = CascadeSeg(config).parse(view)
    common = PROCEDURAL[int(np.bincount(every.categories).argmax())]
    regions = CascadeSeg(config.model_copy(update={"ignore_classes": (common,)})).parse(view)
    assert common not in regions.names and len(regions) == len(every) - every.names.count(common)
    classes = CascadeSeg(config).classify(view.rgb)
    assert (regions.labels[classes == PROCEDURAL.index(common)] == -1).all()


def test_the_holes_of_a_synthetic_view_get_no_region():
    view = make_view(seed=0, size=96)
    depth = view.depth.copy()
    depth[:, :40] = 0.0
    synthetic = dataclasses.replace(view, depth=depth, synthetic=True)
    config = CascadeSegConfig(weights="random", device="cpu", min_region_px=0)
    assert (CascadeSeg(config).parse(synthetic).labels[:, :40] == -1).all()
    kept = CascadeSeg(config.model_copy(update={"drop_holes": False})).parse(synthetic)
    assert (kept.labels[:, :40] >= 0).all()
    real = dataclasses.replace(view, depth=depth)  # a real view's missing depth is content
    assert (CascadeSeg(config).parse(real).labels[:, :40] >= 0).all()


def test_views_of_any_size_parse_to_their_own_size():
    view = View(rgb=np.random.default_rng(0).integers(0, 256, (90, 150, 3), dtype=np.uint8), pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=150, height=90))
    regions = CascadeSeg(RANDOM).parse(view)
    assert regions.labels.shape == (90, 150)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"network": "resnet101dilated"}, "Input should be 'light', 'resnet18dilated' or 'resnet50dilated'"),
        ({"classes": "coco"}, "Input should be 'procedural' or 'ade20k'"),
        ({"image_sizes": []}, "at least 1 item"),
        ({"image_sizes": [4]}, "greater than or equal to 8"),
        ({"min_region_px": -1}, "greater than or equal to 0"),
        ({"connectivity": 6}, "Input should be 4 or 8"),
        ({"ignore_classes": ["wal"]}, r"'wal' is no class of any vocabulary \('ade20k', 'procedural'\); did you mean 'wall'"),
        ({"classes": "procedural", "ignore_classes": ["wal"]}, "'wal' is no class of classes = 'procedural'; did you mean 'wall'"),
        ({"classes": "procedural", "ignore_classes": ["sky"]}, "'sky' is no class of classes = 'procedural'"),
        ({"weights": ""}, "at least 1 character"),
        ({"device": "tpu"}, "Input should be 'auto', 'cpu' or 'cuda'"),
        ({"classes_file": "x"}, "Extra inputs are not permitted"),
    ],
)
def test_bad_config_fails_validation(params, message):
    with pytest.raises(ValidationError, match=message):
        CascadeSegConfig(**params)


def test_ade20k_class_names_validate_against_their_vocabulary():
    assert CascadeSegConfig(classes="ade20k", ignore_classes=["sky", "coffee table"]).ignore_classes == ("sky", "coffee table")
    assert len(ADE20K) == len(set(ADE20K)) == 150 and ADE20K[:4] == ("wall", "building", "sky", "floor") and ADE20K[-1] == "flag"


def test_ignored_classes_are_checked_against_the_weights_vocabulary_when_classes_is_left_out():
    config = CascadeSegConfig(device="cpu", ignore_classes=["sky"])  # an ADE20K class: fine until the weights say otherwise
    with pytest.raises(CheckpointError) as err:
        CascadeSeg(config)
    message = str(err.value)
    assert "\n" not in message and "config field 'ignore_classes': 'sky' is no class of classes = 'procedural'" in message
    assert f"the vocabulary of config field 'weights' = {LIGHT_WEIGHTS!r}" in message
    assert CascadeSeg(CascadeSegConfig(device="cpu", ignore_classes=["wall"]))._ignored.tolist() == [0]


def test_presets_resolve_and_name_the_release_folders(ssga_installed_registry, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for preset, params in CascadeSeg.presets.items():
        assert CascadeSegConfig(**params), preset
    stage = resolve_stage("parser", {"name": "cascade-seg", "preset": "ade20k-resnet50dilated-ppm_deepsup", "image_sizes": [450]}, ssga_installed_registry)
    config = stage.config
    assert (config.weights, config.image_sizes) == ("ade20k-resnet50dilated-ppm_deepsup", (450,))
    assert (config.network, config.classes) == (None, None), "the files say them"
    assert not any({"network", "classes"} & set(params) for params in CascadeSeg.presets.values())
    assert CascadeSeg.presets["ade20k-resnet18dilated-ppm_deepsup"]["image_sizes"] == (300, 375, 450, 525, 600)
    with pytest.raises(MissingWeightsError, match=r"'weights' = 'ade20k-resnet50dilated-ppm_deepsup': no such folder .*encoder_epoch_20\.pth and decoder_epoch_20\.pth"):
        stage.create()
    with pytest.raises(ConfigError, match=r"parser\.network: Input should be"):
        resolve_stage("parser", {"name": "cascade-seg", "network": "vgg"}, ssga_installed_registry)
    assert all(f.description for f in CascadeSegConfig.model_fields.values())


def test_random_weights_caveat_reaches_the_variant_label(ssga_installed_registry):
    def label(parser: dict) -> str:
        config = {"variants": ["PD"], "stages": {"parser": {"name": "cascade-seg", **parser}, "descriptor": {"name": "dense-sift"}}}
        return validate_experiment(config, ssga_installed_registry).variants[0].label

    assert label({"weights": "random"}) == "SIFT-SE (PD) [random weights]"
    assert label({}) == "SIFT-SE (PD)"


@pytest.mark.parametrize("sync_bn", [False, True])
@pytest.mark.parametrize("batches_tracked", [True, False])
def test_a_release_folder_loads_with_or_without_batch_norm_bookkeeping(tmp_path, sync_bn, batches_tracked):
    net = trained_like()
    folder = save_release(tmp_path / "release", net, sync_bn=sync_bn, batches_tracked=batches_tracked)
    parser = CascadeSeg(CascadeSegConfig(weights=str(folder), device="cpu"))
    for mine, theirs in ((parser.net.encoder, net.encoder), (parser.net.decoder, net.decoder)):
        for key, value in theirs.state_dict().items():
            if not key.endswith("num_batches_tracked"):
                assert torch.equal(mine.state_dict()[key], value), key
    view = make_view(seed=4, size=64)
    expected = torch.nn.functional.interpolate(net(_input(view)), (64, 64), mode="bilinear", align_corners=False).softmax(1)[0]
    np.testing.assert_allclose(CascadeSeg(CascadeSegConfig(weights=str(folder), device="cpu", image_sizes=(64,))).probabilities(view.rgb), expected.detach().numpy(), atol=1e-6)


def _input(view: View) -> torch.Tensor:
    from ssga_parser_cascade_seg.model import to_input

    return to_input(view.rgb, view.camera.shape, torch.device("cpu"))


def test_a_relative_folder_is_looked_up_in_the_working_directory(tmp_path, monkeypatch):
    save_release(tmp_path / "mine", trained_like())
    monkeypatch.chdir(tmp_path)
    assert CascadeSeg(CascadeSegConfig(weights="mine", device="cpu")).weights_folder() == tmp_path / "mine"


def test_a_missing_folder_or_file_is_one_line_naming_the_field(tmp_path):
    cases = {
        str(tmp_path / "absent"): "no such folder",
        str(save_release(tmp_path / "r", trained_like()) / FILES["encoder"]): "is a file; set 'weights' to the folder holding",
    }
    partial = tmp_path / "partial"
    partial.mkdir()
    (partial / FILES["encoder"]).write_bytes(b"")
    cases[str(partial)] = "holds no decoder_epoch_20.pth"
    for weights, message in cases.items():
        with pytest.raises(MissingWeightsError) as err:
            CascadeSeg(CascadeSegConfig(weights=weights, device="cpu"))
        text = str(err.value)
        assert "\n" not in text and "parser 'cascade-seg': config field 'weights'" in text and message in text, text


def _truncated(path):
    data = checkpoint_bytes(trained_like().decoder.state_dict())
    path.write_bytes(data[: len(data) // 2])


def _random_bytes(path):
    path.write_bytes(np.random.default_rng(0).bytes(4096))


def _malicious(path):
    torch.save({"state_dict": {"conv_last.4.weight": RunsCode(f"touch {shlex.quote(str(path.parent / 'ran'))}")}}, path)


@pytest.mark.parametrize("damage", [_truncated, _random_bytes, _malicious, lambda path: path.write_bytes(b"not a checkpoint")])
def test_a_broken_or_malicious_file_is_one_line_and_never_runs(tmp_path, damage):
    folder = save_release(tmp_path / "r", trained_like())
    damage(folder / FILES["decoder"])
    with pytest.raises(CheckpointError) as err:
        CascadeSeg(CascadeSegConfig(weights=str(folder), device="cpu"))
    message = str(err.value)
    assert "\n" not in message and "Traceback" not in message and not isinstance(err.value, MissingWeightsError)
    assert f"config field 'weights': {folder / FILES['decoder']} is not a readable checkpoint" in message, message
    assert not (folder / "ran").exists(), "weights_only: the pickle's code never runs"


def test_a_readable_file_of_no_tensors_is_one_line(tmp_path):
    folder = save_release(tmp_path / "r", trained_like())
    (folder / FILES["decoder"]).write_bytes(checkpoint_bytes({"state_dict": {"epoch": 20}}))
    with pytest.raises(CheckpointError, match=r"decoder_epoch_20\.pth holds no state dict of tensors; expected the encoder or decoder") as err:
        CascadeSeg(CascadeSegConfig(weights=str(folder), device="cpu"))
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("edit", "part", "message"),
    [
        (lambda s: s.pop("layer4.1.conv2.weight"), "encoder", r"1 missing: encoder_epoch_20\.pth:layer4\.1\.conv2\.weight"),
        (lambda s: s.update({"fc.weight": torch.zeros(1000, 128)}), "encoder", r"1 unexpected: encoder_epoch_20\.pth:fc\.weight"),
        (lambda s: s.update({"conv1._tmp_running_mean": torch.zeros(16)}), "encoder", r"1 unexpected: encoder_epoch_20\.pth:conv1\._tmp_running_mean"),
        # 20 classes: no vocabulary's count, so the layer is of the wrong shape for the default's 13.
        (
            lambda s: s.update({"conv_last.4.weight": torch.zeros(20, 64, 1, 1)}),
            "decoder",
            r"1 wrong shape: decoder_epoch_20\.pth:conv_last\.4\.weight \(20, 64, 1, 1\) \(expected \(13, 64, 1, 1\)\)",
        ),
        (lambda s: s.pop("conv_last_deepsup.weight"), "decoder", r"1 missing: decoder_epoch_20\.pth:conv_last_deepsup\.weight"),
    ],
)
def test_every_other_key_is_strict(tmp_path, edit, part, message):
    net = trained_like()
    folder = save_release(tmp_path / "r", net, sync_bn=True)
    state = torch.load(folder / FILES[part], weights_only=True)
    edit(state)
    (folder / FILES[part]).write_bytes(checkpoint_bytes(state))
    with pytest.raises(CheckpointError) as err:
        CascadeSeg(CascadeSegConfig(weights=str(folder), device="cpu"))
    text = str(err.value)
    assert "\n" not in text and f"config field 'weights': {folder} matches none of the layouts it loads" in text
    assert "closest: 'light': " in text and re.search(message, text), text


@pytest.fixture(scope="module")
def resnet50_release(tmp_path_factory):
    """An official ResNet50-dilated release folder as CSAIL publishes it (raw state dicts under the release's
    file names), its values random: our network in the official layout with ADE20K's 150 classes."""
    torch.manual_seed(0)
    return save_release(tmp_path_factory.mktemp("official") / "ade20k-resnet50dilated-ppm_deepsup", SceneParser(RESNET50DILATED, len(ADE20K)))


def test_an_official_release_alone_names_its_network_and_classes(resnet50_release):
    # What a user does: weights = the downloaded folder, nothing else.
    parser = CascadeSeg(CascadeSegConfig(weights=str(resnet50_release), device="cpu", image_sizes=(64,)))
    assert (parser.config.network, parser.config.classes) == ("resnet50dilated", "ade20k")
    assert parser.class_names == ADE20K and parser.net.decoder.conv_last[4].out_channels == 150
    assert set(parser.parse(make_view(size=64)).names) <= set(ADE20K)
    copy = pickle.loads(pickle.dumps(parser))  # a worker process loads the same network
    assert (copy.config.network, copy.config.classes, copy.class_names) == ("resnet50dilated", "ade20k", ADE20K)
    light = CascadeSeg(CascadeSegConfig(device="cpu"))
    assert (light.config.network, light.config.classes, light.class_names) == ("light", "procedural", PROCEDURAL)
    random = CascadeSeg(RANDOM)
    assert (random.config.network, random.config.classes) == ("light", "procedural")


def test_ssga_parse_takes_an_official_release_by_weights_alone(resnet50_release, tmp_path, ssga_installed_registry):
    """The command that failed with "does not match the encoder of the 'light' network" unless a preset named the network."""
    import cv2
    from typer.testing import CliRunner

    from ssga_core.cli import app_with_plugin_commands

    cv2.imwrite(str(tmp_path / "wall.png"), make_view(seed=3, size=64).rgb[:, :, ::-1])
    app, runner = app_with_plugin_commands(), CliRunner()
    common = ["parse", str(tmp_path / "wall.png"), "--parser", "cascade-seg", "-o", f"weights={resnet50_release}", "-o", "device=cpu", "--executor", "serial"]
    result = runner.invoke(app, [*common, "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "wall.regions.json").exists()
    wrong = runner.invoke(app, [*common, "-o", "network=light", "--out", str(tmp_path / "wrong")])
    assert wrong.exit_code == 1 and "Traceback" not in wrong.output
    lines = wrong.stderr.strip().splitlines()
    assert len(lines) == 1 and "config field network = 'light' contradicts config field 'weights'" in lines[0], wrong.stderr


def test_a_config_that_contradicts_the_files_is_one_line_naming_both(tmp_path, resnet50_release):
    with pytest.raises(CheckpointError) as err:
        CascadeSeg(CascadeSegConfig(weights=str(resnet50_release), network="light", device="cpu"))
    message = str(err.value)
    assert "\n" not in message and str(resnet50_release) in message
    assert "config field network = 'light' contradicts config field 'weights'" in message and "holds the 'resnet50dilated' layout" in message
    assert "(CSAIL's ADE20K release, the paper's" in message and "leave network out to take the file's" in message
    with pytest.raises(CheckpointError, match=r"classes = 'procedural' contradicts .* with classes = 'ade20k'; leave classes out"):
        CascadeSeg(CascadeSegConfig(weights=str(resnet50_release), classes="procedural", device="cpu"))
    both = CascadeSegConfig(weights=str(resnet50_release), network="resnet18dilated", classes="procedural", device="cpu")
    with pytest.raises(CheckpointError, match=r"config fields network = 'resnet18dilated', classes = 'procedural' contradict config field 'weights'"):
        CascadeSeg(both)
    # Our own files say what they hold, and their keys and shapes say the same.
    ours = save_release(tmp_path / "ours", trained_like(), wrap={"network": "light", "classes": "procedural"})
    with pytest.raises(CheckpointError, match="classes = 'ade20k' contradicts config field 'weights': .* holds the 'light' layout"):
        CascadeSeg(CascadeSegConfig(weights=str(ours), classes="ade20k", device="cpu"))
    assert len(CascadeSeg(CascadeSegConfig(weights=str(ours), device="cpu")).parse(make_view(size=64))) > 0


def test_files_of_no_known_layout_name_the_closest_and_its_first_differences(tmp_path):
    names = ", ".join(repr(layout.name) for layout in LAYOUTS)
    # A light encoder beside a ResNet18-dilated decoder: each file alone is of a known network, the pair is none.
    mixed = save_release(tmp_path / "mixed", trained_like())
    r18 = save_release(tmp_path / "r18", init_weights(SceneParser(RESNET18DILATED, len(ADE20K)), 0))
    (mixed / FILES["decoder"]).write_bytes((r18 / FILES["decoder"]).read_bytes())
    with pytest.raises(CheckpointError) as err:
        CascadeSeg(CascadeSegConfig(weights=str(mixed), device="cpu"))
    message = str(err.value)
    assert "\n" not in message and f"{mixed} matches none of the layouts it loads ({names}); closest: " in message
    assert re.search(r"closest: '(light|resnet18dilated)': \d+ wrong shape: (en|de)coder_epoch_20\.pth:", message), message
    # Another network altogether (an ImageNet classifier's keys).
    other = tmp_path / "other"
    other.mkdir()
    for name in FILES.values():
        (other / name).write_bytes(checkpoint_bytes({"conv1.weight": torch.zeros(64, 3, 7, 7), "fc.weight": torch.zeros(10, 512)}))
    with pytest.raises(CheckpointError, match=rf"{other} matches none of the layouts it loads \({names}\); closest: '\w+': \d+ missing: "):
        CascadeSeg(CascadeSegConfig(weights=str(other), device="cpu"))


def test_random_weights_are_the_same_in_every_instance_and_after_pickling():
    view = make_view(seed=2, size=96)
    a = CascadeSeg(RANDOM)
    b = pickle.loads(pickle.dumps(a))
    np.testing.assert_array_equal(a.classify(view.rgb), b.classify(view.rgb))
    assert CascadeSeg.caveat(RANDOM) == "random weights" and CascadeSeg.caveat(CascadeSegConfig()) == ""


def test_a_bad_image_is_refused():
    with pytest.raises(InputError, match=r"expected an \(H, W, 3\) uint8 RGB image"):
        CascadeSeg(RANDOM).probabilities(np.zeros((8, 8), dtype=np.uint8))


def test_runs_on_the_cpu_and_on_cuda_alike(monkeypatch):
    view = make_view(size=96)
    cpu = CascadeSeg(CascadeSegConfig(weights="random", device="cpu"))
    assert next(cpu.net.parameters()).device.type == "cpu"
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="no CUDA device"):
            CascadeSeg(CascadeSegConfig(weights="random", device="cuda"))
        return
    # Full float32 on the GPU: its default TF32 convolutions round to about 1e-3 (seen on an H100),
    # which would hide a real difference; the device plumbing is what is compared here.
    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", False)
    monkeypatch.setattr(torch.backends.cuda.matmul, "allow_tf32", False)
    gpu = CascadeSeg(CascadeSegConfig(weights="random", device="cuda"))
    np.testing.assert_allclose(cpu.probabilities(view.rgb), gpu.probabilities(view.rgb), atol=1e-4)
