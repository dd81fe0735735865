"""Side by side with the official Patch-NetVLAD code (PyPI ``patchnetvlad`` 0.1.8): same weights, same input.

``patchnetvlad`` is installed with ``--no-deps`` (``requirements-nodeps.txt``). Its model
modules import torchvision, faiss, scikit-learn and tqdm at the top but use none of
them in the forward pass, so each of those that is not installed is stubbed while the
official modules are imported; the official encoder is built here as torchvision builds
``vgg16().features`` (from its layer list), not with this package's code.
"""

from __future__ import annotations

import configparser
import importlib
import importlib.util
import sys
import types

import numpy as np
import pytest
import torch
from torch import nn
from ssga_descriptor_pnv.layout import LIGHT_WIDTHS, VGG16_WIDTHS, patch_grid
from ssga_descriptor_pnv.plugin import Pnv, PnvConfig

from ssga_bench import checkpoint_bytes
from ssga_core import Camera, Pose, View

TOLERANCE = 1e-5
"""Largest absolute difference allowed between our and the official features (measured: ~1e-7)."""


@pytest.fixture
def official(monkeypatch):
    """The official modules: ``(models_generic, local_matcher)``."""
    stubs = {"torchvision": "models", "faiss": None, "sklearn": "neighbors", "tqdm": "auto"}
    for top, sub in stubs.items():
        if top in sys.modules or importlib.util.find_spec(top) is not None:
            continue  # installed: the real one is used
        for name in (top, f"{top}.{sub}") if sub else (top,):
            stub = types.ModuleType(name)
            stub.__version__ = "0"
            stub.NearestNeighbors = stub.tqdm = None
            monkeypatch.setitem(sys.modules, name, stub)
        if sub:
            setattr(sys.modules[top], sub, sys.modules[f"{top}.{sub}"])
    return importlib.import_module("patchnetvlad.models.models_generic"), importlib.import_module("patchnetvlad.models.local_matcher")


def torchvision_vgg16_features(widths) -> nn.Sequential:
    """torchvision's ``vgg.make_layers(cfgs["D"])`` with the given block widths, then ``[:-2]`` as PNV's ``get_backend``."""
    cfg = [widths[0]] * 2 + ["M"] + [widths[1]] * 2 + ["M"] + [widths[2]] * 3 + ["M"] + [widths[3]] * 3 + ["M"] + [widths[4]] * 3 + ["M"]
    layers, channels = [], 3
    for v in cfg:
        if v == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(channels, v, kernel_size=3, padding=1), nn.ReLU(inplace=True)]
            channels = v
    return nn.Sequential(*layers[:-2])


def official_model(models_generic, widths, clusters: int, num_pcs: int):
    parser = configparser.ConfigParser()
    parser["global_params"] = {
        "pooling": "patchnetvlad", "num_clusters": str(clusters), "vladv2": "False",
        "patch_sizes": "5", "strides": "1", "num_pcs": str(num_pcs),
    }
    torch.manual_seed(7)
    model = models_generic.get_model(torchvision_vgg16_features(widths), widths[-1], parser["global_params"], append_pca_layer=True)
    with torch.no_grad():  # random weights everywhere, biases included, and centroids that are not all positive
        for p in model.parameters():
            p.normal_(0.0, 0.05)
        model.pool.centroids.normal_()
    return model.eval()


def official_features(models_generic, model, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(local (P, num_pcs), global (num_pcs,))`` the way PNV's ``feature_extract.py`` computes them (ToTensor, Normalize)."""
    x = torch.from_numpy(rgb).permute(2, 0, 1).float()[None] / 255.0
    x = (x - torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)) / torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    with torch.no_grad():
        vlad_local, vlad_global = model.pool(model.encoder(x))
        local = vlad_local[0]  # (N, K * D, P)
        pca = models_generic.get_pca_encoding(model, local.permute(2, 0, 1).reshape(-1, local.size(1)))
        pca = pca.reshape(local.size(2), local.size(0), -1).permute(1, 2, 0)  # (N, num_pcs, P), as feature_extract.py saves it
        return pca[0].T.numpy(), models_generic.get_pca_encoding(model, vlad_global)[0].numpy()


def _view(size: int, seed: int = 0) -> View:
    rgb = np.random.default_rng(seed).integers(0, 256, (size, size, 3), dtype=np.uint8)
    return View(rgb=rgb, pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=size, height=size))


@pytest.mark.parametrize(
    ("network", "widths", "size"),
    [("vgg16", VGG16_WIDTHS, 112), ("light", LIGHT_WIDTHS, 256)],
    ids=["vgg16-112px", "light-256px"],
)
def test_local_features_match_the_official_code(official, tmp_path, network, widths, size):
    models_generic, _ = official
    model = official_model(models_generic, widths, clusters=16, num_pcs=64)
    # An official-layout checkpoint ({'num_pcs', 'state_dict'}, as add_pca.py saves) must load strictly into ours.
    path = tmp_path / "official_WPCA64.pth.tar"
    path.write_bytes(checkpoint_bytes({"num_pcs": 64, "state_dict": model.state_dict()}))
    ours = Pnv(PnvConfig(weights=str(path), network=network, num_pcs=64, image_size=size, device="cpu"))
    view = _view(size)
    local = ours.extract(view)
    expected_local, expected_global = official_features(models_generic, model, view.rgb)
    patches = (size // 16 - 4) ** 2
    assert local.descriptors.shape == expected_local.shape == (patches, 64)
    diff = np.abs(local.descriptors - expected_local).max()
    print(f"{network} at {size} px: max |ours - official| over {patches} x 64 local features = {diff:.2e}")
    assert diff <= TOLERANCE
    with torch.inference_mode():
        from ssga_descriptor_pnv.model import preprocess

        _, ours_global = ours.net(preprocess(view.rgb, size))
    assert np.abs(ours_global[0].numpy() - expected_global).max() <= TOLERANCE


@pytest.mark.filterwarnings("ignore:torch.meshgrid:UserWarning")  # the official code's call
def test_patch_centres_are_the_official_keypoints(official):
    _, local_matcher = official
    for h, w in ((256, 256), (480, 640)):
        keypoints, indices = local_matcher.calc_keypoint_centers_from_patches({"imageresizeH": h, "imageresizeW": w}, 5, 5, 1, 1)
        ours = patch_grid((h // 16, w // 16), 5, 1)
        # The official centres are the same numbers cast to int (39.5 -> 39).
        np.testing.assert_array_equal(np.floor(ours).astype(int), keypoints.T)
        assert len(ours) == indices.shape[1]
