"""depth-layout: the contract, that it reads the room's shape and not its depth's scale, from RGB alone; regions, weights, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from ssga_descriptor_depth_layout.plugin import DepthLayout, DepthLayoutConfig

from ssga_bench.testing import check_installed
from ssga_core import Camera, CheckpointError, InputError, MissingWeightsError, Pose, Regions, View
from ssga_core.testing import check_descriptor, check_descriptor_in_all_orders, make_view


@pytest.fixture(scope="module")
def packaged() -> DepthLayout:
    return DepthLayout(DepthLayoutConfig(device="cpu"))


class _Known:
    """A stand-in for the depth network that returns a given inverse depth, whatever the image."""

    def __init__(self, inverse: np.ndarray) -> None:
        self.inverse = inverse

    def predict(self, images):
        return np.stack([self.inverse for _ in images])


def _with_network(inverse: np.ndarray) -> DepthLayout:
    descriptor = DepthLayout(DepthLayoutConfig(weights="random", device="cpu"))
    descriptor.depth_network = _Known(inverse.astype(np.float32))
    return descriptor


def _corner(column: int, size: int = 64) -> np.ndarray:
    """Inverse depth of a room corner seen from inside: far at ``column``, nearer towards both sides."""
    u = np.arange(size, dtype=np.float32)
    return np.tile(1.0 / (3.0 - 2.0 * np.abs(u - column) / size), (size, 1))


def _view(size: int = 64, depth: np.ndarray | None = None) -> View:
    rgb = np.random.default_rng(0).integers(0, 255, (size, size, 3), dtype=np.uint8)
    return View(rgb=rgb, pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=size, height=size), depth=depth)


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


def test_is_installed_and_registered(ssga_installed_registry):
    check_installed(ssga_installed_registry, "descriptor", "depth-layout", DepthLayout, "ssga-descriptor-depth-layout")


def test_meets_the_descriptor_contract_in_the_orders_that_describe_what_they_see(packaged):
    check_descriptor(packaged)
    orders = set(check_descriptor_in_all_orders(packaged))
    assert {"D", "PD", "SD", "SPD", "PSD"} <= orders
    assert not orders & {"DS", "DSP", "PDS"}, "a region descriptor cannot be carried through S"


def test_features_are_unit_vectors_of_the_grids_size(packaged):
    for descriptor, grid in ((packaged, 8), (DepthLayout(DepthLayoutConfig(device="cpu", grid=4)), 4)):
        feature = descriptor.describe(make_view(), None)[0]
        assert descriptor.dim == grid**2 and feature.shape == (grid**2,)
        assert np.linalg.norm(feature) == pytest.approx(1.0, abs=1e-5)


def test_neither_the_scale_nor_the_shift_of_the_estimate_counts_but_where_the_room_is_near():
    corner = _corner(24)
    reference = _with_network(corner).describe(_view(), None)[0]
    for scale, shift in ((3.0, 0.0), (0.2, 5.0), (1.0, -0.4)):
        np.testing.assert_allclose(_with_network(scale * corner + shift).describe(_view(), None)[0], reference, atol=1e-5)
    near, far = (_with_network(_corner(c)).describe(_view(), None)[0] for c in (28, 48))
    assert _cos(reference, near) > _cos(reference, far) + 0.1


def test_it_reads_rgb_alone_never_the_views_own_depth(packaged):
    plain = _view(96)
    with_depth = _view(96, depth=np.full((96, 96), 2.0, np.float32))
    np.testing.assert_array_equal(packaged.describe(plain, None), packaged.describe(with_depth, None))


def test_on_a_procedural_home_its_estimate_follows_the_true_depth_layout(packaged):
    """The packaged network's feature against the same feature of each view's true inverse depth: the room's
    shape is what it reads (held-out homes of the network's own training, never evaluated by the benchmark)."""
    from ssga_synthesizer_midas_warp.homes import HELDOUT_SEEDS, render_views

    views = render_views(HELDOUT_SEEDS[0], 12)
    truth = np.stack([packaged.feature(1.0 / np.maximum(d, 0.2)) for d in views.depth])
    estimated = np.stack([packaged.describe(_view_of(rgb), None)[0] for rgb in views.rgb])
    likeness = truth @ estimated.T  # (true view, estimated view)
    own = np.diag(likeness)
    others = likeness[~np.eye(len(own), dtype=bool)]
    assert np.median(own) > 0.85 and others.mean() < np.median(own) - 0.3, (own, others.mean())
    # Rooms share a shape (near at the sides, far ahead), so a view's own truth need not always be its best
    # match; for most views it is (measured: 9 of 12; a view facing a near, flat wall has no shape to read).
    assert (likeness.argmax(axis=0) == np.arange(len(own))).sum() >= 8, likeness.argmax(axis=0)


def test_each_region_is_its_box_of_the_whole_images_depth():
    inverse = _corner(20)
    descriptor = _with_network(inverse)
    labels = np.full((64, 64), -1, np.int32)
    labels[8:40, 4:30] = 0
    labels[63, 63] = 1
    regions = Regions(labels=labels, boxes=np.array([[4, 8, 29, 39], [63, 63, 63, 63]], np.float32))
    whole, first, tiny = descriptor.describe(_view(), regions)
    depth = descriptor.inverse_depth(_view().rgb)
    np.testing.assert_allclose(whole, descriptor.feature(depth), atol=1e-6)
    np.testing.assert_allclose(first, descriptor.feature(depth[8:40, 4:30]), atol=1e-6)
    assert np.isfinite(tiny).all()


def test_random_weights_are_labelled_and_missing_weights_name_this_stages_field(tmp_path):
    assert DepthLayout.caveat(DepthLayoutConfig(weights="random")) == "random weights"
    assert DepthLayout.caveat(DepthLayoutConfig()) == ""
    with pytest.raises(MissingWeightsError, match=r"^descriptor 'depth-layout' \(midas-warp's network\): config field 'weights' = 'nope\.pt'"):
        DepthLayout(DepthLayoutConfig(weights="nope.pt"))
    broken = tmp_path / "broken.pt"
    broken.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="descriptor 'depth-layout'.*broken.pt"):
        DepthLayout(DepthLayoutConfig(weights=str(broken)))


def test_a_run_on_other_views_than_the_networks_homes_says_so():
    assert DepthLayout.out_of_domain(DepthLayoutConfig(), "procedural") == ""
    note = DepthLayout.out_of_domain(DepthLayoutConfig(), "mesh")
    assert "midas-light.pt" in note and "procedural" in note and "'mesh'" in note, note
    assert DepthLayout.out_of_domain(DepthLayoutConfig(weights="random"), "mesh") == ""


def test_a_bad_config_or_image_is_refused(packaged):
    for bad in ({"grid": 0}, {"network": "dpt"}, {"weights": ""}):
        with pytest.raises(ValidationError):
            DepthLayoutConfig(**bad)
    for rgb in (np.zeros((32, 32), np.uint8), np.zeros((32, 32, 3), np.float32)):
        with pytest.raises(InputError, match="depth-layout.*uint8"):
            packaged.inverse_depth(rgb)


def _view_of(rgb: np.ndarray) -> View:
    h, w = rgb.shape[:2]
    return View(rgb=rgb, pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=w, height=h))


def test_the_evaluation_scores_a_network_that_sees_the_truth_as_perfect_and_a_wrong_one_below():
    from ssga_descriptor_depth_layout.evaluate import layout_agreement

    depth = np.stack([1.0 / _corner(c) for c in (8, 24, 40, 56)])
    rgb = np.zeros((4, 64, 64, 3), np.uint8)
    rgb[:, 0, 0, 0] = np.arange(4)  # each image says which depth it shows

    class Sees:
        def __init__(self, shift: int) -> None:
            self.shift = shift

        def predict(self, images):
            return np.stack([1.0 / depth[(int(image[0, 0, 0]) + self.shift) % 4] for image in images])

    descriptor = DepthLayout(DepthLayoutConfig(weights="random", device="cpu"))
    descriptor.depth_network = Sees(0)
    right = layout_agreement(descriptor, rgb, depth, np.zeros(4))
    assert right["views"] == 4 and right["own_median"] == pytest.approx(1.0, abs=1e-5) and right["own_best_share"] == 1.0
    descriptor.depth_network = Sees(1)  # every view given another's depth
    wrong = layout_agreement(descriptor, rgb, depth, np.zeros(4))
    assert wrong["own_mean"] < right["own_mean"] - 0.1 and wrong["own_best_share"] == 0.0
