"""Dense SIFT: the contract, the grid, what SIFT and RootSIFT guarantee, and the registration."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from ssga_descriptor_dense_sift.plugin import (
    DenseSift,
    DenseSiftConfig,
    grid_positions,
    keypoint_octave,
    root_sift,
)

from ssga_core import Camera, InputError, Pose, View
from ssga_bench import BoWConfig, NotFittedError
from ssga_bench import COLOUR_DIM, colour_histograms
from ssga_bench.testing import check_installed
from ssga_core.testing import check_descriptor, check_descriptor_in_all_orders, make_view


def _texture(width: int = 288, height: int = 256, seed: int = 0) -> np.ndarray:
    """A smooth random grey texture, RGB uint8: gradients everywhere, nothing repeats."""
    noise = np.random.default_rng(seed).random((height, width)).astype(np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), 3)
    tex = ((tex - tex.min()) / (tex.max() - tex.min()) * 255).astype(np.uint8)
    return np.repeat(tex[..., None], 3, axis=2)


def _view(rgb: np.ndarray) -> View:
    h, w = rgb.shape[:2]
    return View(rgb=np.ascontiguousarray(rgb), pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=w, height=h))


def test_is_installed_and_registered(ssga_installed_registry):
    check_installed(ssga_installed_registry, "descriptor", "dense-sift", DenseSift, "ssga-descriptor-dense-sift")


def test_meets_the_descriptor_contract():
    check_descriptor(DenseSift())


def test_runs_in_every_order():
    check_descriptor_in_all_orders(DenseSift())


def test_configured_from_a_nested_mapping(ssga_installed_registry):
    d = ssga_installed_registry.create("descriptor", "dense-sift", root_sift=True, bow={"k": 50, "similarity": "centroid"})
    assert d.dim == 50 and d.config.bow.similarity == "centroid" and d.config.root_sift


def test_144_features_at_patch_netvlads_patch_centres():
    local = DenseSift().extract(make_view())
    assert local.descriptors.shape == (144, 128)
    # PNV at 256 x 256: 5 x 5-cell patches on the 16 x 16 conv5_3 map, centred at 39.5 + 16 j px.
    centres = 39.5 + 16 * np.arange(12)
    np.testing.assert_allclose(np.unique(local.positions[:, 0]), centres, atol=1e-4)
    np.testing.assert_allclose(np.unique(local.positions[:, 1]), centres, atol=1e-4)


def test_uniform_layout_and_grid_scale_with_the_image():
    pos = grid_positions((384, 512), 12, "uniform")
    np.testing.assert_allclose(np.unique(pos[:, 0]), (np.arange(12) + 0.5) * 512 / 12 - 0.5, atol=1e-4)
    np.testing.assert_allclose(np.unique(pos[:, 1]), (np.arange(12) + 0.5) * 384 / 12 - 0.5, atol=1e-4)
    local = DenseSift(DenseSiftConfig(grid=6)).extract(_view(_texture(320, 192)))
    assert len(local) == 36 and Camera(width=320, height=192).contains(local.positions).all()


def test_keypoint_octave_matches_the_size_and_never_upsamples():
    assert keypoint_octave(3.2) == 0  # OpenCV's base blur: octave 0, layer 0
    assert keypoint_octave(6.4) == 1  # twice the blur: the next octave
    assert keypoint_octave(12.8 * 2 ** (1 / 3)) == 2 | (1 << 8)  # octave 2, layer 1
    assert keypoint_octave(1.0) == 0  # smaller than the base blur: no upsampled octave -1


def test_a_shifted_patch_gives_a_near_identical_descriptor():
    tex = _texture()
    d = DenseSift()
    a = d.extract(_view(tex[:, :256])).descriptors.reshape(12, 12, 128)
    # The content moves 16 px left: one PNV grid step, so keypoint j + 1 of `a` is keypoint j of `b`.
    b = d.extract(_view(tex[:, 16:272])).descriptors.reshape(12, 12, 128)
    same = (a[3:9, 4:9] * b[3:9, 3:8]).sum(-1)  # away from the borders, where new content enters
    neighbour = (a[3:9, 3:8] * b[3:9, 3:8]).sum(-1)  # the same grid slot: 16 px apart in the scene
    assert same.min() > 0.99
    assert (same > neighbour + 0.02).all()


def test_descriptors_are_unit_length_and_brightness_invariant():
    tex = _texture()[:, :256]
    d = DenseSift()
    a = d.extract(_view(tex)).descriptors
    brighter = np.clip(tex.astype(int) * 1.2 + 10, 0, 255).astype(np.uint8)
    b = d.extract(_view(brighter)).descriptors
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, rtol=1e-5)
    assert (a * b).sum(1).min() > 0.98


def test_root_sift_is_the_hellinger_map_of_sift():
    tex = _view(_texture()[:, :256])
    plain = DenseSift(DenseSiftConfig(root_sift=False)).extract(tex).descriptors
    rooted = DenseSift(DenseSiftConfig(root_sift=True)).extract(tex).descriptors
    np.testing.assert_allclose(rooted, root_sift(plain), atol=1e-6)  # RootSIFT ignores SIFT's own scale
    np.testing.assert_allclose(np.linalg.norm(rooted, axis=1), 1.0, rtol=1e-5)
    # Euclidean distance between RootSIFT vectors is the Hellinger distance of the L1-normalised SIFT histograms.
    p = plain / plain.sum(1, keepdims=True)
    hellinger = 2.0 - 2.0 * np.sqrt(p[:, None, :] * p[None, :, :]).sum(-1)
    euclidean = ((rooted[:, None, :] - rooted[None, :, :]) ** 2).sum(-1)
    np.testing.assert_allclose(euclidean, hellinger, atol=1e-5)


def test_a_flat_image_gives_zero_not_nan():
    flat = np.full((256, 256, 3), 128, np.uint8)
    for root in (False, True):
        local = DenseSift(DenseSiftConfig(root_sift=root)).extract(_view(flat))
        assert np.isfinite(local.descriptors).all()


def test_pooling_needs_fit_and_fit_needs_enough_features():
    d = DenseSift()
    local = d.extract(make_view())
    with pytest.raises(NotFittedError, match="'dense-sift'"):
        d.pool(local, [np.arange(len(local))])
    small = DenseSift(DenseSiftConfig(grid=4))  # 16 features a view: 5 views are too few for k = 100
    with pytest.raises(InputError, match="descriptor 'dense-sift'.*lower bow.k"):
        small.fit([make_view(seed=s) for s in range(5)])
    DenseSift(DenseSiftConfig(grid=4, bow=BoWConfig(k=20))).fit([make_view(seed=s) for s in range(2)])


def test_colour_keeps_the_histogram_of_each_keypoints_own_window():
    # Colour itself (the histograms, the dictionary, the mixed cosine) is the bag of words' (tests/bench/test_bow.py);
    # dense SIFT gives it the square its SIFT window is centred on: the keypoint's size, 24 px at 256 x 256.
    view = make_view(seed=3)
    plain, coloured = DenseSift(DenseSiftConfig()), DenseSift(DenseSiftConfig(colour=0.75))
    a, own = coloured.extract(view), plain.extract(view)
    assert coloured.colour_window(view) == 24 and coloured.colour_window(make_view(size=512)) == 48
    np.testing.assert_array_equal(a.descriptors[:, :128], own.descriptors)
    np.testing.assert_array_equal(a.descriptors[:, 128:], colour_histograms(view.rgb, own.positions, 24))
    assert coloured.dim == 100 + COLOUR_DIM
