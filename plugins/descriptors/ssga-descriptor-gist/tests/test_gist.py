"""GIST: the contract, that it keeps the layout a bag of words forgets, its colour weight, regions, and bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from ssga_descriptor_gist.plugin import Gist, GistConfig

from ssga_bench.testing import check_installed
from ssga_core import Camera, InputError, Pose, Regions, View
from ssga_core.testing import check_descriptor, check_descriptor_in_all_orders, make_view


def _view(rgb: np.ndarray) -> View:
    h, w = rgb.shape[:2]
    return View(rgb=np.ascontiguousarray(rgb), pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=w, height=h))


def _room(corner: int, size: int = 256) -> np.ndarray:
    """A wall, a floor below a slanted skirting line, and a room corner (a vertical edge) at column ``corner``."""
    rgb = np.full((size, size, 3), (180, 170, 150), np.uint8)
    rgb[:, corner:] = (140, 135, 120)
    for u in range(size):
        rgb[int(0.7 * size + 0.1 * (u - corner)) :, u] = (90, 70, 50)
    return rgb


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


def test_is_installed_and_registered(ssga_installed_registry):
    check_installed(ssga_installed_registry, "descriptor", "gist", Gist, "ssga-descriptor-gist")


def test_meets_the_descriptor_contract_in_the_orders_that_describe_what_they_see():
    descriptor = Gist(GistConfig())
    check_descriptor(descriptor)
    orders = set(check_descriptor_in_all_orders(descriptor))
    assert {"D", "PD", "SD", "SPD", "PSD"} <= orders
    assert not orders & {"DS", "DSP", "PDS"}, "a region descriptor cannot be carried through S"


def test_features_are_unit_vectors_of_the_configured_size():
    for config, dim in ((GistConfig(), 8 * 8 * 8 + 8 * 8 * 3), (GistConfig(grid=4, orientations=6, colour=0.0), 4 * 4 * 6)):
        descriptor = Gist(config)
        feature = descriptor.describe(make_view(), None)[0]
        assert descriptor.dim == dim and feature.shape == (dim,)
        assert np.linalg.norm(feature) == pytest.approx(1.0, abs=1e-5)


def test_the_same_room_seen_from_another_place_differs_in_layout_not_in_content():
    """Where the corner stands moves the feature; a small move less than a large one, and a bag of the
    same pixels (the image mirrored) is not the same image."""
    gist = Gist(GistConfig())
    here, near, far = (gist.feature(_room(c)) for c in (96, 104, 180))
    mirrored = gist.feature(np.ascontiguousarray(_room(96)[:, ::-1]))
    assert _cos(here, near) > _cos(here, far) + 0.05
    assert _cos(here, near) > _cos(here, mirrored) + 0.05


def test_it_reads_the_scene_not_the_resolution():
    gist = Gist(GistConfig())
    small = _room(100)
    large = cv2.resize(small, (512, 512), interpolation=cv2.INTER_LINEAR)
    assert _cos(gist.feature(small), gist.feature(large)) > 0.98


def test_colour_weighs_the_colour_layout_and_zero_ignores_it():
    rgb = _room(120)
    grey = np.repeat(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)[..., None], 3, axis=2)  # the same grey, no colour
    np.testing.assert_allclose(Gist(GistConfig(colour=0.0)).feature(rgb), Gist(GistConfig(colour=0.0)).feature(grey), atol=1e-6)
    likeness = [_cos(Gist(GistConfig(colour=w)).feature(rgb), Gist(GistConfig(colour=w)).feature(grey)) for w in (0.25, 0.5, 1.0)]
    assert likeness[0] < 0.999 and likeness[0] > likeness[1] > likeness[2], likeness


def test_each_region_is_described_as_its_box_alone():
    gist = Gist(GistConfig())
    rgb = _room(90)
    labels = np.full((256, 256), -1, np.int32)
    labels[40:200, 30:150] = 0
    labels[10:60, 160:250] = 1
    regions = Regions(labels=labels, boxes=np.array([[30, 40, 149, 199], [160, 10, 249, 59]], np.float32))
    whole, first, second = gist.describe(_view(rgb), regions)
    np.testing.assert_allclose(whole, gist.feature(rgb), atol=1e-6)
    np.testing.assert_allclose(first, gist.feature(rgb[40:200, 30:150]), atol=1e-6)
    np.testing.assert_allclose(second, gist.feature(rgb[10:60, 160:250]), atol=1e-6)


def test_a_region_one_pixel_wide_still_gets_a_feature():
    gist = Gist(GistConfig())
    labels = np.full((64, 64), -1, np.int32)
    labels[10, 63] = 0
    regions = Regions(labels=labels, boxes=np.array([[63, 10, 63, 10]], np.float32))
    features = gist.describe(_view(_room(20, size=64)), regions)
    assert features.shape == (2, gist.dim) and np.isfinite(features).all()


@pytest.mark.parametrize("rgb", [np.zeros((32, 32), np.uint8), np.zeros((32, 32, 3), np.float32)])
def test_an_image_that_is_not_rgb_uint8_is_an_input_error(rgb):
    with pytest.raises(InputError, match="gist.*uint8"):
        Gist(GistConfig()).feature(rgb)
