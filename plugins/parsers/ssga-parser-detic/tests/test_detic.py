"""The detic parser: registration, contract, regions from detections, files and their errors, rows without weights."""

from __future__ import annotations

import json
import pickle
import shlex

import numpy as np
import pytest
import torch
from pydantic import ValidationError
from ssga_bench.testing import RunsCode, WallWorkspaceSource
from ssga_core.testing import check_parser, check_parser_in_all_orders, make_view
from ssga_core.testing import stages as stand_in_stages
from ssga_core.testing.stages import ShiftWarp
from ssga_parser_detic.checkpoint import ZS_WEIGHT_KEYS
from ssga_parser_detic.model import DeticR50, detect, init_random
from ssga_parser_detic.plugin import (
    LAYOUTS,
    LVIS_EMBEDDINGS,
    LVIS_NAMES,
    R50_CHECKPOINT,
    R50_URL,
    DeticConfig,
    DeticParser,
    owners,
    pixel_centre_boxes,
)

from ssga_bench import ProtocolConfig, build_dataset, checkpoint_bytes, run_experiment, validate_experiment
from ssga_core import CheckpointError, ConfigError, MissingWeightsError, Pose, resolve_stage


@pytest.fixture(scope="module")
def config(vocabulary) -> DeticConfig:
    """Random weights at 256 px (the test views' size: no resize), the test vocabulary; the mask head runs on
    every detection kept (about 0.5 G multiply-adds each), so a few keep the tests fast."""
    return DeticConfig(weights="random", device="cpu", test_size=256, max_detections=6, **vocabulary)


@pytest.fixture(scope="module")
def parser(config) -> DeticParser:
    return DeticParser(config)


def test_is_installed_and_registered(ssga_installed_registry):
    entry = ssga_installed_registry.entry("parser", "detic")
    assert entry.cls is DeticParser
    assert entry.plugin.distribution == "ssga-parser-detic"
    assert DeticParser.tag() == "DE"
    assert [layout.name for layout in entry.cls.layouts] == ["resnet50-in21k"] and R50_URL in entry.cls.layouts[0].source


def test_meets_the_parser_contract(parser):
    check_parser(parser, make_view(seed=1))


def test_runs_in_every_order(vocabulary):
    small = DeticParser(DeticConfig(weights="random", device="cpu", test_size=64, max_detections=3, **vocabulary))
    assert "SPD" in check_parser_in_all_orders(small)


def test_random_weights_are_labelled(config):
    assert DeticParser.caveat(config) == "random weights"


def test_regions_are_the_detections_each_pixel_to_the_best(parser):
    view = make_view(seed=2)
    regions = parser.parse(view)
    found = detect(parser.net, view.rgb, parser.settings)
    assert 0 < len(regions) <= len(found)
    assert len(regions.names) == len(regions) and regions.categories.dtype == np.int32 and regions.scores.dtype == np.float32
    assert (regions.scores > parser.config.score_threshold).all() and (np.diff(regions.scores) <= 0).all()
    assert regions.names == tuple(f"thing {c}" for c in regions.categories)
    # Region k is the k-th detection that kept a pixel; each pixel goes to the best detection covering it.
    kept = [k for k in range(len(found)) if np.isin(k, owners(found.masks))]
    np.testing.assert_array_equal(regions.scores, found.scores[kept])
    np.testing.assert_array_equal(regions.categories, found.classes[kept])
    covered = found.masks.any(axis=0)
    np.testing.assert_array_equal(regions.labels >= 0, covered)
    best = np.where(covered, np.argmax(np.where(found.masks, found.scores[:, None, None], -1.0), axis=0), -1)
    np.testing.assert_array_equal(np.array(kept)[regions.labels[covered]], best[covered])
    # Boxes are the detector's own, in pixel-centre coordinates.
    np.testing.assert_allclose(regions.boxes, pixel_centre_boxes(found.boxes[kept], view.camera.shape))


def test_overlapping_masks_go_to_the_highest_score():
    masks = np.zeros((3, 4, 5), dtype=bool)
    masks[0, 1:3, 1:3] = True  # the best detection
    masks[1, 0:4, 0:4] = True  # covers the first
    masks[2, 0, 4] = True
    np.testing.assert_array_equal(
        owners(masks),
        [[1, 1, 1, 1, 2], [1, 0, 0, 1, -1], [1, 0, 0, 1, -1], [1, 1, 1, 1, -1]],
    )
    assert (owners(np.zeros((0, 2, 3), dtype=bool)) == -1).all()


def test_detector_boxes_become_pixel_centre_boxes_inside_the_image():
    # Pixel i spans [i, i + 1) for the detector and is centred at i for ssga.
    got = pixel_centre_boxes(np.array([[10.0, 20.0, 30.5, 40.0], [0.0, 0.0, 64.0, 48.0]]), (48, 64))
    np.testing.assert_allclose(got, [[9.5, 19.5, 30.0, 39.5], [0.0, 0.0, 63.0, 47.0]])


def test_holes_of_a_synthetic_view_get_no_region(parser, config):
    view = make_view(seed=0)
    right = view.pose.rotation()[:, 0]
    target = Pose(view.pose.x + 0.4 * right[0], view.pose.y + 0.4 * right[1], view.pose.yaw, view.pose.height)
    synthetic = ShiftWarp().synthesize(view, target).view
    holes = ~synthetic.valid_depth()
    assert holes.any()
    assert (parser.parse(synthetic).labels[holes] == -1).all()
    kept = DeticParser(config.model_copy(update={"drop_holes": False})).parse(synthetic)
    assert (kept.labels[holes] >= 0).any()


def test_parses_the_same_after_pickling(parser):
    view = make_view(seed=3)
    again = pickle.loads(pickle.dumps(parser))
    np.testing.assert_array_equal(again.parse(view).labels, parser.parse(view).labels)


# --------------------------------------------------------------------------- files


def test_without_the_checkpoint_the_field_and_file_are_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(MissingWeightsError) as caught:
        DeticParser()
    message = str(caught.value)
    assert f"config field 'weights' = '{R50_CHECKPOINT}': no such file" in message and R50_URL in message
    assert "\n" not in message


def test_without_the_vocabulary_the_field_and_file_are_named(vocabulary, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(MissingWeightsError, match=r"config field 'vocabulary' = 'lvis_v1_clip_a\+cname.npy': no such file .*CLIP text embeddings"):
        DeticParser(DeticConfig(weights="random", class_names=vocabulary["class_names"]))
    with pytest.raises(MissingWeightsError, match="config field 'class_names' = 'lvis_v1_train_cat_info.json': no such file"):
        DeticParser(DeticConfig(weights="random", vocabulary=vocabulary["vocabulary"]))


def test_names_must_match_the_embeddings(vocabulary, tmp_path):
    short = tmp_path / "names.txt"
    short.write_text("cup\nplate\n")
    with pytest.raises(CheckpointError, match="names 2 classes, but the vocabulary .* embeds 40"):
        DeticParser(DeticConfig(weights="random", vocabulary=vocabulary["vocabulary"], class_names=str(short)))


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (np.zeros((5, 300), dtype=np.float32), r"holds a \(5, 300\) array of float32; expected a \(classes, 512\) array"),
        (np.array(["a", "b"]), "array of <U1"),
        (b"not an array", "is not a .npy array"),
    ],
)
def test_bad_embedding_files_are_one_line_errors(vocabulary, tmp_path, content, message):
    path = tmp_path / "bad.npy"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        np.save(path, content)
    with pytest.raises(CheckpointError, match=f"config field 'vocabulary': {path}.*{message}") as caught:
        DeticParser(DeticConfig(weights="random", vocabulary=str(path), class_names=vocabulary["class_names"]))
    assert "\n" not in str(caught.value)


def test_lvis_category_files_give_names_in_id_order(vocabulary_dir, tmp_path):
    categories = [{"id": k + 1, "name": f"name_{k}", "synonyms": []} for k in range(40)]
    path = tmp_path / "cats.json"
    path.write_text(json.dumps(categories[::-1]))  # the file's order does not matter, the ids do
    parser = DeticParser(DeticConfig(weights="random", vocabulary=str(vocabulary_dir / "vocab.npy"), class_names=str(path)))
    assert parser.names[:3] == ("name_0", "name_1", "name_2")
    path.write_text(json.dumps([f"n{k}" for k in range(40)]))
    assert DeticParser(DeticConfig(weights="random", vocabulary=str(vocabulary_dir / "vocab.npy"), class_names=str(path))).names[-1] == "n39"


def test_the_released_file_alone_loads_with_the_vocabulary_beside_it(vocabulary_dir, tmp_path):
    """What a user does: the three downloaded files in one folder, weights = the checkpoint, nothing else. Here a
    detectron2 checkpoint (with its bookkeeping and training vocabulary) of other weights under the release's name:
    the loaded network is the saved one, parses as the network it was saved from, and a worker loads the same."""
    source = init_random(DeticR50(), 1)
    model = {**source.state_dict(), **{key: torch.randn(512, 1204) for key in ZS_WEIGHT_KEYS}}
    folder = tmp_path / "detic"
    folder.mkdir()
    (folder / R50_CHECKPOINT).write_bytes(checkpoint_bytes({"model": model, "__author__": "Detic", "iteration": 1}))
    (folder / LVIS_EMBEDDINGS).write_bytes((vocabulary_dir / "vocab.npy").read_bytes())
    (folder / LVIS_NAMES).write_text(json.dumps((vocabulary_dir / "names.txt").read_text().splitlines()))
    parser = DeticParser(DeticConfig(weights=str(folder / R50_CHECKPOINT), device="cpu", test_size=256, max_detections=6))
    assert DeticParser.caveat(parser.config) == ""
    loaded = parser.net.state_dict()
    assert all(torch.equal(loaded[k], v) for k, v in source.state_dict().items())
    source.set_vocabulary(torch.from_numpy(np.load(vocabulary_dir / "vocab.npy").astype(np.float32)))
    view = make_view(seed=4)
    labels = detect_labels(source.eval(), view, parser)
    np.testing.assert_array_equal(parser.parse(view).labels, labels)
    copy = pickle.loads(pickle.dumps(parser))
    assert copy.names == parser.names and copy.net is parser.net  # the same file: the process's one network
    np.testing.assert_array_equal(copy.parse(view).labels, labels)


def detect_labels(net, view, parser) -> np.ndarray:
    found = detect(net, view.rgb, parser.settings)
    labels = owners(found.masks)
    kept = np.flatnonzero(np.bincount(labels[labels >= 0], minlength=len(found)))
    lut = np.full(len(found) + 1, -1)
    lut[kept] = np.arange(len(kept))
    return lut[labels]


def _truncated(path):
    data = checkpoint_bytes({"model": {"backbone.top_block.p6.weight": torch.zeros(256, 256, 3, 3)}})
    path.write_bytes(data[: len(data) // 2])


def _malicious(path):
    torch.save({"model": {"pixel_mean": RunsCode(f"touch {shlex.quote(str(path.parent / 'ran'))}")}}, path)


@pytest.mark.parametrize(
    "damage",
    [
        lambda path: path.write_bytes(b"not a checkpoint"),
        _truncated,
        lambda path: path.write_bytes(np.random.default_rng(0).bytes(4096)),
        _malicious,
    ],
    ids=["text", "truncated", "random-bytes", "malicious-pickle"],
)
def test_a_broken_or_malicious_checkpoint_is_one_line_and_never_runs(vocabulary, tmp_path, damage):
    path = tmp_path / R50_CHECKPOINT
    damage(path)
    with pytest.raises(CheckpointError, match=f"config field 'weights': {path} is not a readable checkpoint") as caught:
        DeticParser(DeticConfig(weights=str(path), **vocabulary))
    assert "\n" not in str(caught.value) and "Traceback" not in str(caught.value) and not isinstance(caught.value, MissingWeightsError)
    assert not (tmp_path / "ran").exists(), "weights_only: the pickle's code never runs"


def test_a_file_of_another_network_names_the_layout_it_came_closest_to(vocabulary, tmp_path):
    path = tmp_path / "resnet.pth"  # an ImageNet classifier's keys, as a detectron2 checkpoint
    path.write_bytes(checkpoint_bytes({"model": {"conv1.weight": torch.zeros(64, 3, 7, 7), "fc.weight": torch.zeros(10, 2048)}}))
    with pytest.raises(CheckpointError) as caught:
        DeticParser(DeticConfig(weights=str(path), **vocabulary))
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"parser 'detic': config field 'weights': {path} matches none of the layouts it loads ('resnet50-in21k')")
    assert "closest: 'resnet50-in21k': 351 missing: backbone.bottom_up.base.conv1.weight" in message
    assert "2 unexpected: conv1.weight, fc.weight" in message
    assert LAYOUTS[0].name == "resnet50-in21k"


# --------------------------------------------------------------------------- configs and experiments


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"score_threshold": 1.0}, "less than 1"),
        ({"nms_threshold": 0.0}, "greater than 0"),
        ({"max_detections": 0}, "greater than or equal to 1"),
        ({"resize": "square"}, "'max-size' or 'shortest-edge'"),
        ({"test_size": 16}, "greater than or equal to 32"),
        ({"vocabulary": ""}, "at least 1 character"),
        ({"threshold": 0.3}, "Extra inputs are not permitted"),
    ],
)
def test_bad_config_fails_validation(params, message):
    with pytest.raises(ValidationError, match=message):
        DeticConfig(**params)


def test_presets_resolve_and_every_field_is_described(ssga_installed_registry):
    stage = resolve_stage("parser", {"name": "detic", "preset": "demo", "score_threshold": 0.3}, ssga_installed_registry)
    assert stage.config == DeticConfig(resize="shortest-edge", test_size=800, max_size=1333, score_threshold=0.3)
    assert resolve_stage("parser", {"name": "detic", "preset": "all-classes"}, ssga_installed_registry).config.one_class_per_proposal is False
    with pytest.raises(ConfigError, match=r"parser\.max_detections: Input should be greater than or equal to 1"):
        resolve_stage("parser", {"name": "detic", "max_detections": 0}, ssga_installed_registry)
    assert all(f.description for f in DeticConfig.model_fields.values())


def test_experiment_rows_without_weights_say_so_and_the_others_run(ssga_plugin_set, tmp_path, monkeypatch):
    """The paper's P-DE rows on a machine without Detic's checkpoint: reported "not run, no weights" with the field."""
    from ssga_bench import testing as stand_in_workspaces

    monkeypatch.chdir(tmp_path)
    ssga_plugin_set.load_entry_points()
    ssga_plugin_set.register(stand_in_stages, "stand-ins")
    ssga_plugin_set.register(stand_in_workspaces, "stand-in-workspaces")
    registry = ssga_plugin_set.registry()
    stages = {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-patch-colour"}, "synthesizer": {"name": "test-shift"}}
    detic = {"name": "detic"}
    exp = validate_experiment(
        {
            "workspace": {"name": "test-wall"},
            "stages": stages,
            "variants": ["PD", {"variant": "PDS", "parser": detic}, {"variant": "PSD", "parser": detic}],
            "fuser": {"name": "rrf"},
            "training": {"epochs": 2, "hidden": 16},
        },
        registry,
    )
    dataset = build_dataset(WallWorkspaceSource().open(), tmp_path / "ds", source={"name": "test-wall"}, protocol=ProtocolConfig(cells=2, test_per_class=1, seed=4))
    report, _ = run_experiment(exp, dataset, tmp_path / "run")
    assert report.variants == ["PC-ST (PD)"]
    assert sorted(report.not_run) == ["PC-DE (PDS)", "PC-DE (PSD)"]
    for why in report.not_run.values():
        assert why.startswith("no weights: parser 'detic': config field 'weights'") and R50_CHECKPOINT in why
    assert "| PC-DE (PDS) ⚠ | not run |" in report.markdown()


def test_a_view_of_another_size_is_parsed_in_its_own_pixels(parser):
    view = make_view(seed=5, size=160)
    regions = parser.parse(view)
    assert regions.labels.shape == (160, 160)
    assert (regions.boxes[:, 2:] <= 159).all()
