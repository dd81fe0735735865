"""CNN-RRF: it learns, its features are reciprocal ranks of the right crops, training is cached, checkpoints load strictly.

Every network here is a tiny member of the VGG family (4 to 32 channels, 32 px inputs),
so the whole file runs in seconds on one CPU core.
"""

from __future__ import annotations

import pickle
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from ssga_descriptor_cnn_rrf import training as cnn_training
from ssga_descriptor_cnn_rrf.plugin import CnnRrf, CnnRrfConfig
from ssga_descriptor_cnn_rrf.training import expand_box
from ssga_descriptor_cnn_rrf.vgg import VGG

from ssga_bench import NotFittedError, checkpoint_bytes, validate_experiment
from ssga_core import Camera, CheckpointError, InputError, Pose, Regions, View
from ssga_bench.testing import check_installed
from ssga_core.testing import check_descriptor, check_descriptor_in_all_orders, make_view

TINY = {"width": 1 / 16, "hidden": 32, "pool": 1, "input_size": 32, "min_crop": 4.0, "batch_size": 16}
"""A VGG16 layout 16 times narrower (4...32 channels) on 32 px inputs."""

HUES = [(220, 40, 40), (40, 200, 40), (40, 60, 220), (220, 200, 30)]


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def tiny(tmp_path: Path, **overrides) -> CnnRrf:
    return CnnRrf(CnnRrfConfig(**{**TINY, "cache_dir": tmp_path / "cache", **overrides}))


def _view(rgb: np.ndarray) -> View:
    h, w = rgb.shape[:2]
    return View(rgb=np.ascontiguousarray(rgb), pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=w, height=h))


def colour_view(hue: tuple[int, int, int], seed: int, size: int = 48) -> View:
    """A flat colour with pixel noise: classes that differ in colour only."""
    noise = np.random.default_rng(seed).normal(0.0, 12.0, (size, size, 3))
    return _view(np.clip(np.array(hue, float) + noise, 0, 255).astype(np.uint8))


def colour_set(per_class: int = 2) -> tuple[list[View], list[int]]:
    views, labels = [], []
    for c, hue in enumerate(HUES):
        for s in range(per_class):
            views.append(colour_view(hue, seed=10 * c + s))
            labels.append(10 + 3 * c)  # class ids need not be 0..C-1
    return views, labels


def quadrants(size: int = 64) -> tuple[View, Regions, list[int]]:
    """An image of four colour quadrants, the quadrants as regions (in a shuffled order), and each region's class."""
    rgb = np.zeros((size, size, 3), np.uint8)
    half = size // 2
    corners = [(0, 0), (half, 0), (0, half), (half, half)]
    for c, ((x, y), hue) in enumerate(zip(corners, HUES)):
        rgb[y : y + half, x : x + half] = colour_view(hue, seed=50 + c, size=half).rgb
    order = [2, 0, 3, 1]  # region k is quadrant order[k]
    labels = np.zeros((size, size), np.int32)
    for k, q in enumerate(order):
        x, y = corners[q]
        labels[y : y + half, x : x + half] = k
    return _view(rgb), Regions.from_labels(labels), [10 + 3 * q for q in order]


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Iterator[CnnRrf]:
    """A tiny classifier trained on the four colours (about 2 s on one core)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    d = tiny(tmp_path_factory.mktemp("cnn"), steps=40)
    views, labels = colour_set()
    d.fit(views, labels)
    yield d
    torch.set_num_threads(threads)


# -- registration, config -----------------------------------------------------------------


def test_is_installed_and_registered(ssga_installed_registry):
    check_installed(ssga_installed_registry, "descriptor", "cnn-rrf", CnnRrf, "ssga-descriptor-cnn-rrf")


def test_the_default_is_the_light_preset_trained_here_and_presets_validate():
    default = CnnRrfConfig()
    assert default == CnnRrfConfig(**CnnRrf.presets["light"])
    assert default.weights == "scratch" and CnnRrf.caveat(default) == ""
    vgg16 = CnnRrfConfig(**CnnRrf.presets["vgg16"])
    assert (vgg16.arch, vgg16.width, vgg16.hidden, vgg16.pool, vgg16.batch_norm) == ("vgg16", 1.0, 4096, 7, False)


def test_dim_and_features_need_fit(tmp_path):
    d = tiny(tmp_path)
    with pytest.raises(NotFittedError, match="descriptor 'cnn-rrf' is not fitted: dim is the number of place classes"):
        _ = d.dim
    with pytest.raises(NotFittedError, match="not fitted"):
        d.describe(colour_view(HUES[0], 0), None)


# -- learning and features ----------------------------------------------------------------


def test_it_learns_a_separable_set(trained):
    assert list(trained.classes) == [10, 13, 16, 19] and trained.dim == 4
    assert trained.training is not None and trained.training.accuracy == 1.0  # chance: 0.25
    fresh = [colour_view(hue, seed=99 + c) for c, hue in enumerate(HUES)]  # unseen noise
    assert trained.accuracy(fresh, [10, 13, 16, 19]) == 1.0
    p = trained.classify(fresh[2])
    assert p.shape == (4,) and abs(p.sum() - 1.0) < 1e-5 and p.argmax() == 2


def test_features_are_reciprocal_ranks_whole_image_first_then_regions(trained, tmp_path):
    view, regions, region_classes = quadrants()
    features = trained.describe(view, regions)
    assert features.shape == (1 + len(regions), 4)
    for row in features:  # each node: a permutation of 1/1 ... 1/C
        np.testing.assert_allclose(np.sort(row)[::-1], 1.0 / np.arange(1, 5), rtol=1e-6)
    # Row 0 is the whole image: the same as describing it without regions, and the classifier's own ranking.
    np.testing.assert_array_equal(features[0], trained.describe(view, None)[0])
    np.testing.assert_array_equal(np.argsort(-features[0], kind="stable"), np.argsort(-trained.classify(view), kind="stable"))
    # Row k + 1 is region k: each quadrant's crop ranks its own colour first (without a margin, which
    # would show the tiny network strips of the neighbouring colours).
    tight = tiny(tmp_path, weights=str(trained.cache_file), region_margin=0.0)
    tight.fit(*colour_set())
    top = tight.classes[tight.describe(view, regions)[1:].argmax(axis=1)]
    assert list(top) == region_classes


def test_the_fitted_state_makes_the_same_descriptor_elsewhere(trained, tmp_path):
    view, regions, _ = quadrants()
    state = trained.state_dict()
    assert list(state["classes"]) == [10, 13, 16, 19] and all(isinstance(a, np.ndarray) for a in state.values())
    copy = tiny(tmp_path)
    copy.load_state_dict(state)  # no fit: the classifier as it was trained
    np.testing.assert_array_equal(copy.describe(view, regions), trained.describe(view, regions))
    assert copy.dim == 4 and copy.training is None
    with pytest.raises(InputError, match="fitted state is not a vgg16_bn .* of 4 classes"):
        tiny(tmp_path, hidden=16).load_state_dict(state)
    with pytest.raises(InputError, match="fitted state without 'classes'"):
        tiny(tmp_path).load_state_dict({k: v for k, v in state.items() if k != "classes"})


def test_region_crops_grow_by_the_margin_and_stay_inside():
    assert expand_box([10, 20, 29, 39], (100, 100), 0.1, 4) == (8, 18, 32, 42)  # 20 px side -> 24 px
    assert expand_box([0, 0, 9, 9], (100, 100), 0.5, 4) == (0, 0, 20, 20)  # shifted back inside, not cut
    assert expand_box([50, 50, 50, 50], (100, 100), 0.0, 16) == (43, 43, 59, 59)  # one pixel -> min_crop
    assert expand_box([0, 0, 99, 99], (100, 100), 0.2, 4) == (0, 0, 100, 100)
    assert expand_box([np.nan] * 4, (60, 80), 0.1, 4) == (0, 0, 80, 60)  # no box: the whole image


def test_meets_the_descriptor_contract(tmp_path):
    check_descriptor(tiny(tmp_path, steps=3))  # fit without labels: each view its own class


def test_runs_in_every_order(tmp_path):
    check_descriptor_in_all_orders(tiny(tmp_path, steps=3))


def test_one_class_needs_no_training(tmp_path):
    d = tiny(tmp_path, steps=3)
    d.fit([make_view(size=64)], [7])
    assert d.training is None and d.dim == 1
    np.testing.assert_array_equal(d.describe(make_view(seed=1, size=64), None), [[1.0]])


# -- cache --------------------------------------------------------------------------------


def test_a_second_fit_loads_the_cached_classifier(tmp_path, monkeypatch):
    views, labels = colour_set(per_class=1)
    first = tiny(tmp_path, steps=5)
    first.fit(views, labels)
    assert first.training is not None and first.cache_file is not None and first.cache_file.parent == tmp_path / "cache"
    assert [p.name for p in (tmp_path / "cache").iterdir()] == [first.cache_file.name]  # no temporary file left

    def no_training(*args, **kwargs):
        raise AssertionError("trained again")

    monkeypatch.setattr(cnn_training, "train", no_training)
    again = tiny(tmp_path, steps=5, device="cpu", describe_batch=2)  # runtime fields: same key
    again.fit(views, labels)
    assert again.training is None and again.cache_file == first.cache_file
    trained = first._fitted().state_dict()  # the weights come back exactly, wherever the first fit ran
    loaded = again._fitted().state_dict()
    assert trained.keys() == loaded.keys() and all(torch.equal(trained[k].cpu(), loaded[k].cpu()) for k in trained)
    if first.device == again.device:  # a CUDA-trained first describes with other rounding than the CPU, which can flip a rank
        view, regions, _ = quadrants()
        np.testing.assert_array_equal(again.describe(view, regions), first.describe(view, regions))


@pytest.mark.parametrize("change", ["config", "image", "labels"])
def test_a_changed_config_image_or_label_trains_again(tmp_path, change):
    views, labels = colour_set(per_class=1)
    first = tiny(tmp_path, steps=5)
    first.fit(views, labels)
    config: dict = {"steps": 5}
    if change == "config":
        config["seed"] = 1
    elif change == "image":
        rgb = views[0].rgb.copy()
        rgb[0, 0, 0] ^= 1
        views[0] = _view(rgb)
    else:
        labels = [labels[1], labels[0], *labels[2:]]
    second = tiny(tmp_path, **config)
    second.fit(views, labels)
    assert second.training is not None and second.cache_file != first.cache_file
    assert len(list((tmp_path / "cache").iterdir())) == 2


def test_a_damaged_cache_file_is_trained_again(tmp_path, capsys):
    views, labels = colour_set(per_class=1)
    first = tiny(tmp_path, steps=5)
    first.fit(views, labels)
    first.cache_file.write_bytes(b"not a checkpoint")
    second = tiny(tmp_path, steps=5)
    second.fit(views, labels)
    assert second.training is not None and "ignoring a damaged cache file" in capsys.readouterr().err
    third = tiny(tmp_path, steps=5)
    third.fit(views, labels)
    assert third.training is None


# -- checkpoints --------------------------------------------------------------------------


def torchvision_vgg16_shapes(width: float = 1.0, hidden: int = 4096, classes: int = 1000) -> dict[str, tuple[int, ...]]:
    """The names and shapes of torchvision's ``vgg16()`` state dict (channels times ``width``), written out by hand."""
    channels = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512, 512, 512, 512]
    indices = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28]
    shapes, c_in = {}, 3
    for i, c in zip(indices, channels):
        c = round(c * width)
        shapes[f"features.{i}.weight"], shapes[f"features.{i}.bias"] = (c, c_in, 3, 3), (c,)
        c_in = c
    for i, (rows, cols) in zip((0, 3, 6), ((hidden, c_in * 7 * 7), (hidden, hidden), (classes, hidden))):
        shapes[f"classifier.{i}.weight"], shapes[f"classifier.{i}.bias"] = (rows, cols), (rows,)
    return shapes


def torchvision_vgg16_state(width: float = 1.0, hidden: int = 4096, classes: int = 1000) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    return {k: torch.randn(s, generator=gen) * 0.05 for k, s in torchvision_vgg16_shapes(width, hidden, classes).items()}


def test_the_full_vgg16_has_torchvisions_names_and_shapes():
    with torch.device("meta"):  # shapes only, no memory
        ours = {k: tuple(v.shape) for k, v in VGG("vgg16", 1000).state_dict().items()}
    theirs = torchvision_vgg16_shapes()
    assert list(ours) == list(theirs) and ours == theirs
    assert sum(np.prod(s) for s in ours.values()) == 138_357_544  # torchvision's vgg16 parameter count


FILE_NET = {**TINY, "batch_norm": False, "pool": 7, "hidden": 16}
"""The layout of torchvision_vgg16_state(width=1/16, hidden=16)."""


def test_an_imagenet_file_initialises_the_network_with_a_new_place_head(tmp_path):
    state = torchvision_vgg16_state(width=1 / 16, hidden=16)
    path = tmp_path / "vgg16-imagenet.pth"
    path.write_bytes(checkpoint_bytes(state))  # a bare state dict, as torchvision's files are
    d = tiny(tmp_path, **FILE_NET, weights=str(path), steps=0)
    views, labels = colour_set(per_class=1)
    d.fit(views, labels)
    loaded = d._net.state_dict()
    for key, value in state.items():
        if key.startswith("classifier.6"):
            assert loaded[key].shape[0] == 4  # the place head, not ImageNet's 1000 classes
        else:
            torch.testing.assert_close(loaded[key].cpu(), value)  # the network may sit on CUDA
    assert d.dim == 4 and CnnRrf.caveat(d.config) == ""


def test_a_file_with_the_place_head_is_used_as_is(tmp_path, monkeypatch):
    state = torchvision_vgg16_state(width=1 / 16, hidden=16, classes=4)
    path = tmp_path / "places.pt"
    path.write_bytes(checkpoint_bytes({"state_dict": state}))
    monkeypatch.setattr(cnn_training, "train", lambda *a, **k: pytest.fail("a finished classifier was trained"))
    d = tiny(tmp_path, **FILE_NET, weights=str(path), steps=50)
    views, labels = colour_set(per_class=1)
    d.fit(views, labels)
    for key, value in d._net.state_dict().items():
        torch.testing.assert_close(value.cpu(), state[key])  # the network may sit on CUDA


def test_a_cached_classifier_is_a_checkpoint_for_weights(trained, tmp_path, monkeypatch):
    monkeypatch.setattr(cnn_training, "train", lambda *a, **k: pytest.fail("a finished classifier was trained"))
    d = tiny(tmp_path, steps=40, weights=str(trained.cache_file))
    views, labels = colour_set()
    d.fit(views, labels)
    view, regions, _ = quadrants()
    np.testing.assert_array_equal(d.describe(view, regions), trained.describe(view, regions))
    with pytest.raises(CheckpointError, match="classifies other place classes"):
        d.fit(views, [c + 1 for c in labels])


@pytest.mark.parametrize(
    "content, message",
    [
        (b"garbage", "is not a readable checkpoint"),
        (
            "wrong-width",
            r"config field width = 0.0625 contradicts config field 'weights': .*w.pt holds the 'vgg16' layout .* with width = 0.125; leave width out",
        ),
        ("unknown", r"matches none of the layouts it loads \('vgg16', 'vgg16_bn', 'vgg11', 'vgg11_bn'\); closest: 'vgg16': 1 missing: features.0.bias"),
        ("missing", "no such file"),
    ],
)
def test_a_bad_weights_file_is_one_line_naming_the_field_and_the_file(tmp_path, content, message):
    path = tmp_path / "w.pt"
    if content == "wrong-width":
        path.write_bytes(checkpoint_bytes(torchvision_vgg16_state(width=1 / 8, hidden=16)))
    elif content == "unknown":
        state = torchvision_vgg16_state(width=1 / 16, hidden=16)
        del state["features.0.bias"]
        path.write_bytes(checkpoint_bytes(state))
    elif isinstance(content, bytes):
        path.write_bytes(content)
    with pytest.raises(CheckpointError, match=message) as err:  # when the descriptor is made, before any work
        tiny(tmp_path, **FILE_NET, weights=str(path))
    text = str(err.value)
    assert "\n" not in text and "'weights'" in text and "w.pt" in text


def test_a_head_of_neither_imagenet_nor_the_places_is_refused_at_fit(tmp_path):
    path = tmp_path / "w.pt"
    path.write_bytes(checkpoint_bytes(torchvision_vgg16_state(width=1 / 16, hidden=16, classes=7)))
    d = tiny(tmp_path, **FILE_NET, weights=str(path))
    views, labels = colour_set(per_class=1)
    with pytest.raises(CheckpointError, match=r"1000-class \(ImageNet\) or 4-class \(place\) last layer: 2 wrong shape: classifier.6.weight \(7, 16\)"):
        d.fit(views, labels)
    with pytest.raises(NotFittedError):  # a failed fit leaves nothing half-loaded
        _ = d.dim


def test_a_file_alone_sets_the_network_it_holds(tmp_path):
    # torchvision's VGG16 layout (narrowed to 1/16 here) with no network field in the config.
    path = tmp_path / "vgg16-397923af.pth"
    path.write_bytes(checkpoint_bytes(torchvision_vgg16_state(width=1 / 16, hidden=16)))
    d = CnnRrf(CnnRrfConfig(weights=str(path), cache=False, device="cpu", steps=0))
    assert (d.config.arch, d.config.batch_norm, d.config.width, d.config.hidden, d.config.pool) == ("vgg16", False, 1 / 16, 16, 7)
    views, labels = colour_set(per_class=1)
    d.fit(views, labels)
    assert d.dim == 4
    state = d.state_dict()
    elsewhere = pickle.loads(pickle.dumps(CnnRrf(CnnRrfConfig(weights=str(path), cache=False, device="cpu"))))
    elsewhere.load_state_dict(state)  # a worker makes the same network from the same config
    view, regions, _ = quadrants()
    np.testing.assert_array_equal(elsewhere.describe(view, regions), d.describe(view, regions))
    light = tmp_path / "light.pt"  # a light classifier trained here: batch norm, width 0.125
    light.write_bytes(checkpoint_bytes({"state_dict": VGG("vgg16", 4, width=0.125, hidden=256, pool=2, batch_norm=True).state_dict()}))
    assert CnnRrf(CnnRrfConfig(weights=str(light), cache=False)).config.batch_norm is True


def test_a_file_is_also_found_in_torchs_hub_cache(tmp_path, monkeypatch):
    hub = tmp_path / "hub"
    (hub / "checkpoints").mkdir(parents=True)
    (hub / "checkpoints" / "vgg16-tiny.pth").write_bytes(checkpoint_bytes(torchvision_vgg16_state(width=1 / 16, hidden=16)))
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(hub))
    monkeypatch.chdir(tmp_path)
    d = tiny(tmp_path, **FILE_NET, weights="vgg16-tiny.pth", steps=0)
    d.fit(*colour_set(per_class=1))
    assert d.dim == 4
    with pytest.raises(CheckpointError, match=r"'weights' = 'other.pth': no such file .*not in torch's hub cache"):
        tiny(tmp_path, **FILE_NET, weights="other.pth").fit(*colour_set(per_class=1))


# -- labels -------------------------------------------------------------------------------


def test_random_weights_are_labelled_and_scratch_is_not(ssga_installed_registry):
    def labels(weights: str) -> list[str]:
        config = {
            "variants": ["D", "PD"],
            "stages": {"descriptor": {"name": "cnn-rrf", "weights": weights}, "parser": {"name": "slico"}},
        }
        return [v.label for v in validate_experiment(config, ssga_installed_registry).variants]

    assert labels("random") == ["CNN (D) [random weights]", "CNN-SL (PD) [random weights]"]
    assert labels("scratch") == ["CNN (D)", "CNN-SL (PD)"]


def test_random_weights_are_untrained_but_seeded(tmp_path, monkeypatch):
    monkeypatch.setattr(cnn_training, "train", lambda *a, **k: pytest.fail("random weights were trained"))
    views, labels = colour_set(per_class=1)
    a, b = tiny(tmp_path, weights="random"), tiny(tmp_path, weights="random")
    a.fit(views, labels)
    b.fit(views, labels)
    view = colour_view(HUES[1], 5)
    np.testing.assert_array_equal(a.describe(view, None), b.describe(view, None))
    assert not (tmp_path / "cache").exists()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_gives_the_cpu_numbers(trained, tmp_path):
    gpu = tiny(tmp_path, device="cuda", weights=str(trained.cache_file))
    views, labels = colour_set()
    gpu.fit(views, labels)
    view, regions, _ = quadrants()
    np.testing.assert_allclose(
        gpu.scores(view, gpu.crops(view, regions)), trained.scores(view, trained.crops(view, regions)), atol=1e-4
    )
