"""The pnv descriptor: registration, contract, shapes and positions, loading errors, caveats, packaged weights."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch
from ssga_descriptor_pnv.layout import LIGHT_WIDTHS, VGG16_WIDTHS
from ssga_descriptor_pnv.model import PatchNetVLAD
from ssga_descriptor_pnv.plugin import LIGHT_WEIGHTS, WEIGHTS_DIR, Pnv, PnvConfig

from ssga_bench import BoWConfig, checkpoint_bytes, validate_experiment
from ssga_bench.testing import one_line_checkpoint_error, packaged_provenance
from ssga_core import Camera, CheckpointError, ConfigError, InputError, Pose, View, resolve_stage
from ssga_core.testing import check_descriptor, check_descriptor_in_all_orders, make_view

RANDOM = PnvConfig(weights="random", device="cpu")
SMALL = PnvConfig(weights="random", device="cpu", image_size=128, bow=BoWConfig(k=16))
"""Views described at 128 x 128: 16 features each (a quarter of the cost), for the slow contract runs."""


def _view(width: int = 256, height: int = 256, seed: int = 0) -> View:
    rgb = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    return View(rgb=rgb, pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=width, height=height))


def _checkpoint(tmp_path, net: torch.nn.Module, name: str = "w.pt") -> str:
    path = tmp_path / name
    path.write_bytes(checkpoint_bytes({"num_pcs": 512, "state_dict": net.state_dict()}))
    return str(path)


def test_is_installed_and_registered(ssga_installed_registry):
    entry = ssga_installed_registry.entry("descriptor", "pnv")
    assert entry.cls is Pnv
    assert entry.plugin.distribution == "ssga-descriptor-pnv"


def test_meets_the_descriptor_contract():
    check_descriptor(Pnv(RANDOM))


def test_runs_in_every_order():
    check_descriptor_in_all_orders(Pnv(SMALL))


def test_144_unit_features_of_512_dims_at_the_patch_centres():
    local = Pnv(RANDOM).extract(make_view())
    assert local.descriptors.shape == (144, 512) and local.descriptors.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(local.descriptors, axis=1), 1.0, rtol=1e-5)
    centres = 39.5 + 16 * np.arange(12)  # 5 x 5-cell patches of the 16 x 16 conv5_3 map, 16 px apart
    np.testing.assert_allclose(local.positions[:12, 0], centres)  # row by row: u varies first
    np.testing.assert_allclose(local.positions[::12, 1], centres)


def test_colour_sits_beside_the_patch_features_and_leaves_the_words_alone():
    from ssga_bench import COLOUR_DIM, colour_histograms

    view = make_view()
    plain, coloured = Pnv(SMALL), Pnv(SMALL.model_copy(update={"colour": 0.5}))
    a, own = coloured.extract(view), plain.extract(view)
    np.testing.assert_array_equal(a.descriptors[:, :-COLOUR_DIM], own.descriptors)
    np.testing.assert_array_equal(a.descriptors[:, -COLOUR_DIM:], colour_histograms(view.rgb, own.positions, 26))
    views = [make_view(seed=s) for s in range(2)]
    plain.fit(views)
    coloured.fit(views)
    np.testing.assert_array_equal(coloured.bow.centroids, plain.bow.centroids)
    assert coloured.pool(a, [np.arange(len(a))]).shape == (1, 16 + COLOUR_DIM)


def test_other_sizes_are_resized_to_256_and_positions_scaled_back():
    d = Pnv(RANDOM)
    view = _view(320, 192)
    local = d.extract(view)
    assert local.descriptors.shape == (144, 512)
    np.testing.assert_allclose(local.positions[:12, 0], (40 + 16 * np.arange(12)) * 320 / 256 - 0.5, atol=1e-4)
    np.testing.assert_allclose(local.positions[::12, 1], (40 + 16 * np.arange(12)) * 192 / 256 - 0.5, atol=1e-4)
    assert view.camera.contains(local.positions).all()
    native = Pnv(PnvConfig(weights="random", device="cpu", image_size=None)).extract(view)
    assert len(native) == (320 // 16 - 4) * (192 // 16 - 4)
    with pytest.raises(InputError, match="too small"):
        Pnv(PnvConfig(weights="random", device="cpu", image_size=None)).extract(_view(64, 64))
    with pytest.raises(ValueError, match="smaller than patch_size"):
        PnvConfig(image_size=64)


def test_the_same_view_gives_the_same_features_and_another_view_others():
    d = Pnv(RANDOM)
    a, b = d.extract(make_view(seed=1)).descriptors, d.extract(make_view(seed=1)).descriptors
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - d.extract(make_view(seed=2)).descriptors).max() > 0.02


def test_random_weights_are_the_same_in_every_instance_and_after_pickling():
    view = make_view()
    a = Pnv(RANDOM).extract(view).descriptors
    copy = pickle.loads(pickle.dumps(Pnv(RANDOM)))
    np.testing.assert_array_equal(copy.extract(view).descriptors, a)


def test_random_weights_caveat_reaches_the_variant_label(ssga_installed_registry):
    def label(descriptor: dict) -> str:
        config = {"variants": ["PD"], "stages": {"parser": {"name": "slico"}, "descriptor": {"name": "pnv", **descriptor}}}
        return validate_experiment(config, ssga_installed_registry).variants[0].label

    assert label({"weights": "random"}) == "P-SL (PD) [random weights]"
    assert label({}) == "P-SL (PD)"


def test_a_missing_file_is_one_line_naming_the_field_and_the_file(tmp_path):
    one_line_checkpoint_error(
        lambda: Pnv(PnvConfig(weights=str(tmp_path / "absent.pth.tar"))), "'weights'", "absent.pth.tar", "descriptor 'pnv'"
    )


def test_a_corrupt_file_is_one_line(tmp_path):
    bad = tmp_path / "corrupt.pth.tar"
    bad.write_bytes(b"\x80\x02 not a checkpoint")
    with pytest.raises(CheckpointError, match="corrupt.pth.tar is not a readable checkpoint") as err:
        Pnv(PnvConfig(weights=str(bad)))
    assert "\n" not in str(err.value) and "'weights'" in str(err.value)


def test_an_official_file_alone_names_its_network_and_sizes(tmp_path):
    # What a user does: weights = the downloaded file, nothing else.
    vgg = PatchNetVLAD(VGG16_WIDTHS, 8, 128)
    d = Pnv(PnvConfig(weights=_checkpoint(tmp_path, vgg, "mapillary_WPCA128.pth.tar"), device="cpu"))
    assert (d.config.network, d.config.num_pcs) == ("vgg16", 128)
    assert d.net.pool.clusters == 8 and d.extract(make_view()).descriptors.shape[1] == 128
    copy = pickle.loads(pickle.dumps(d))  # a worker process loads the same network
    assert (copy.config.network, copy.config.num_pcs) == ("vgg16", 128)
    light = Pnv(PnvConfig(weights=LIGHT_WEIGHTS, device="cpu"))
    assert (light.config.network, light.config.num_pcs) == ("light", 512)


def test_a_config_that_contradicts_the_file_is_one_line_naming_both(tmp_path):
    vgg = _checkpoint(tmp_path, PatchNetVLAD(VGG16_WIDTHS, 16, 512), "mapillary_WPCA512.pth.tar")
    message = one_line_checkpoint_error(lambda: Pnv(PnvConfig(weights=vgg, network="light")), "mapillary_WPCA512.pth.tar")
    assert "config field network = 'light' contradicts config field 'weights'" in message and "holds the 'vgg16' layout" in message
    assert "the official Patch-NetVLAD releases" in message
    with pytest.raises(CheckpointError, match=r"num_pcs = 128 contradicts .* with num_pcs = 512; leave num_pcs out"):
        Pnv(PnvConfig(weights=vgg, num_pcs=128))


def test_a_file_of_no_known_layout_names_the_closest_and_its_first_differences(tmp_path):
    state = PatchNetVLAD(LIGHT_WIDTHS, 16, 512).state_dict()
    del state["WPCA.0.bias"]
    state["pool.conv.bias"] = torch.zeros(16)  # a VLAD v2 file: assignment bias
    path = tmp_path / "v2.pt"
    path.write_bytes(checkpoint_bytes({"state_dict": state}))
    message = one_line_checkpoint_error(
        lambda: Pnv(PnvConfig(weights=str(path))), "matches none of the layouts it loads ('light', 'vgg16')"
    )
    assert "closest: 'light': 1 missing: WPCA.0.bias; 1 unexpected: pool.conv.bias" in message
    wrong_model = tmp_path / "resnet.pt"  # another network altogether
    wrong_model.write_bytes(checkpoint_bytes({"conv1.weight": torch.zeros(64, 3, 7, 7), "fc.weight": torch.zeros(10, 512)}))
    with pytest.raises(CheckpointError, match=r"matches none of the layouts .* closest: '(light|vgg16)': \d+ missing: encoder.0.weight"):
        Pnv(PnvConfig(weights=str(wrong_model)))


def test_clusters_are_read_from_the_file(tmp_path):
    net = PatchNetVLAD(LIGHT_WIDTHS, clusters=8, num_pcs=512)
    d = Pnv(PnvConfig(weights=_checkpoint(tmp_path, net, "k8.pt"), device="cpu"))
    assert d.net.pool.clusters == 8 and d.net.WPCA[0].in_channels == 8 * 128
    assert Pnv.caveat(d.config) == ""


def test_presets_name_the_official_files(ssga_installed_registry, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    stage = resolve_stage("descriptor", {"name": "pnv", "preset": "pittsburgh"}, ssga_installed_registry)
    assert stage.config.weights == "pittsburgh_WPCA512.pth.tar"  # the file says its network
    with pytest.raises(CheckpointError, match="'weights' = 'pittsburgh_WPCA512.pth.tar': no such file"):
        stage.create()
    assert Pnv.presets["mapillary"]["weights"] == "mapillary_WPCA512.pth.tar"
    with pytest.raises(ConfigError, match="no preset 'tokyo'"):
        resolve_stage("descriptor", {"name": "pnv", "preset": "tokyo"}, ssga_installed_registry)


def test_the_packaged_weights_load_and_differ_from_random_ones():
    trained = Pnv(PnvConfig(device="cpu"))
    assert trained.config.weights == LIGHT_WEIGHTS and not trained.random_weights
    view = make_view()
    a, b = trained.extract(view).descriptors, Pnv(RANDOM).extract(view).descriptors
    assert a.shape == b.shape == (144, 512)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, rtol=1e-5)
    assert np.abs(a - b).max() > 0.1


def test_the_packaged_weights_carry_their_provenance():
    provenance = packaged_provenance(WEIGHTS_DIR / LIGHT_WEIGHTS, "ssga_descriptor_pnv.train")
    assert min(provenance["train_seeds"]) >= 1000 and not set(provenance["train_seeds"]) & set(provenance["heldout_seeds"])
    heldout = provenance["figures"]["heldout"]
    assert heldout["trained"]["netvlad"]["recall@1"] > heldout["init"]["netvlad"]["recall@1"]


def test_runs_on_the_cpu_and_on_cuda_alike(monkeypatch):
    view = make_view()
    cpu = Pnv(PnvConfig(device="cpu"))
    assert next(cpu.net.parameters()).device.type == "cpu"
    a = cpu.extract(view).descriptors
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="no CUDA device"):
            Pnv(PnvConfig(device="cuda"))
        return
    # Full float32 on the GPU: its default TF32 convolutions round to about 1e-3 (seen on an H100),
    # which would hide a real difference; the device plumbing is what is compared here.
    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", False)
    monkeypatch.setattr(torch.backends.cuda.matmul, "allow_tf32", False)
    b = Pnv(PnvConfig(device="cuda")).extract(view).descriptors
    np.testing.assert_allclose(a, b, atol=1e-4)
