"""cascade-seg's batch path: ``parse_many`` gives each view what ``parse`` gives it, whatever the batch,
in one network call per scale and input size (on a GPU; on the CPU one call per image, which measured faster)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
import torch
from ssga_bench.testing import network_inputs, whole_batches_on_cpu
from ssga_bench.testing import one_torch_thread as torch_at_one_thread
from ssga_core.testing import make_view
from ssga_parser_cascade_seg.model import predict
from ssga_parser_cascade_seg.plugin import CascadeSeg, CascadeSegConfig

from ssga_core import Camera, InputError, Pose, View

PACKAGED = CascadeSegConfig(device="cpu")
MULTISCALE = CascadeSegConfig(device="cpu", image_sizes=(96, 128, 160))
RANDOM = CascadeSegConfig(weights="random", device="cpu")


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """With the other core busy, two torch threads wait on each other (2-3x slower): one thread, as the runner's workers."""
    with torch_at_one_thread():
        yield


def _view(width: int, height: int, seed: int) -> View:
    rgb = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    return View(rgb=rgb, pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=width, height=height))


def _views() -> list[View]:
    """Two views of one size, one a little smaller (scaled to the same inputs: a scale sets the shorter side), one wide."""
    return [make_view(seed=1, size=128), make_view(seed=2, size=128), make_view(seed=3, size=120), _view(150, 90, seed=4)]


@contextmanager
def network_calls(parser: CascadeSeg) -> Iterator[list[tuple[int, ...]]]:
    """The input shape ``(N, H, W)`` of each call of ``parser``'s network while the block runs."""
    with network_inputs(parser.net) as calls:
        shapes: list[tuple[int, ...]] = []
        yield shapes
    shapes.extend((n, h, w) for n, _, h, w in calls)


@pytest.fixture
def whole_batches():
    """Each same-size group in one call on the CPU too, as on a GPU: the batched network call runs here."""
    with whole_batches_on_cpu():
        yield


@pytest.mark.parametrize("config", [PACKAGED, MULTISCALE, RANDOM], ids=["packaged", "multiscale", "random"])
def test_a_batch_gives_each_view_its_single_regions(whole_batches, config):
    parser = CascadeSeg(config)
    views = _views()
    many = parser.parse_many(views)
    for view, got in zip(views, many, strict=True):
        one = parser.parse(view)
        np.testing.assert_array_equal(got.labels, one.labels)
        np.testing.assert_array_equal(got.categories, one.categories)
        assert got.names == one.names
        np.testing.assert_allclose(got.boxes, one.boxes, rtol=0, atol=0)
        # Measured (CPU, one torch thread): scores differ by 0.0, the probabilities by 0.0 single-scale
        # and 1.8e-7 at most multi-scale (against model.predict, one image per call).
        np.testing.assert_allclose(got.scores, one.scores, rtol=0, atol=1e-6)
    assert sum(len(r) for r in many) > len(many), "the regions are not trivial"


@pytest.mark.parametrize("config", [PACKAGED, MULTISCALE], ids=["packaged", "multiscale"])
def test_batched_probabilities_are_csails_test_per_image(whole_batches, config):
    parser = CascadeSeg(config)
    images = [view.rgb for view in _views()]
    for rgb, got in zip(images, parser.probabilities_many(images), strict=True):
        expected = predict(parser.net, rgb, config.image_sizes, config.max_size, config.padding).numpy()
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-6)


def test_each_scale_is_one_call_per_input_size(whole_batches):
    parser = CascadeSeg(MULTISCALE)
    with network_calls(parser) as calls:
        parser.parse_many(_views())
    # The 128 and 120 px views reach the network at the same size at each scale and share its call;
    # the 150 x 90 view has its own size at every scale.
    assert calls == [(3, 96, 96), (1, 96, 160), (3, 128, 128), (1, 128, 216), (3, 160, 160), (1, 160, 272)]


def test_a_bad_image_fails_the_batch_before_the_network_runs(whole_batches):
    parser = CascadeSeg(RANDOM)
    with network_calls(parser) as calls, pytest.raises(InputError, match=r"expected an \(H, W, 3\) uint8 RGB image"):
        parser.probabilities_many([make_view(seed=1, size=64).rgb, np.zeros((8, 8), dtype=np.uint8)])
    assert calls == []


def test_on_the_cpu_each_image_is_its_own_call():
    parser = CascadeSeg(RANDOM)
    with network_calls(parser) as calls:
        parser.parse_many([make_view(seed=s, size=64) for s in range(3)])
    assert calls == [(1, 256, 256)] * 3  # scaled to image_sizes = (256,)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_on_cuda_a_batch_is_one_call_and_agrees_with_single_views_and_the_cpu():
    config = CascadeSegConfig(device="cuda")
    parser = CascadeSeg(config)
    views = [make_view(seed=s, size=128) for s in range(4)]
    with network_calls(parser) as calls:
        many = parser.probabilities_many([view.rgb for view in views])
    assert calls == [(4, 256, 256)]
    cpu = CascadeSeg(PACKAGED)
    for view, got in zip(views, many, strict=True):
        # cuDNN may pick other (TF32) kernels for another batch size: rounding in the convolutions only
        # (on an H100, 26 of 212,992 probabilities differed from the CPU's by more than 1e-3, at most 1.6e-3).
        np.testing.assert_allclose(got, parser.probabilities(view.rgb), rtol=0, atol=5e-3)
        np.testing.assert_allclose(got, cpu.probabilities(view.rgb), rtol=0, atol=5e-3)
