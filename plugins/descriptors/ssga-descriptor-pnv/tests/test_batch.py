"""pnv's batch path: ``extract_many`` gives each view what ``extract`` gives it, whatever the batch,
in one network call per same-size group (on a GPU; on the CPU one call per view, which measured faster)."""

from __future__ import annotations


import numpy as np
import pytest
import torch
from ssga_bench.testing import network_inputs, whole_batches_on_cpu
from ssga_bench.testing import one_torch_thread as torch_at_one_thread
from ssga_core.testing import make_view
from ssga_descriptor_pnv.plugin import Pnv, PnvConfig

from ssga_core import Camera, InputError, Pose, View

RANDOM = PnvConfig(weights="random", device="cpu")


def _view(width: int, height: int, seed: int) -> View:
    rgb = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    return View(rgb=rgb, pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=width, height=height))


def _views() -> list[View]:
    """Three benchmark-like views and one of another size (resized to image_size like the others)."""
    return [make_view(seed=1), make_view(seed=2), make_view(seed=3), _view(320, 192, seed=4)]


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """With the other core busy, two torch threads wait on each other (2-3x slower): one thread, as the runner's workers."""
    with torch_at_one_thread():
        yield


def network_calls(d: Pnv):
    """The batch size of each call of ``d``'s network while the block runs."""
    return network_inputs(d.net)


@pytest.fixture
def whole_batches():
    """Each same-size group in one call on the CPU too, as on a GPU: the batched network call runs here."""
    with whole_batches_on_cpu():
        yield


def _assert_same(many, views, d: Pnv) -> None:
    for view, got in zip(views, many, strict=True):
        one = d.extract(view)
        np.testing.assert_array_equal(got.positions, one.positions)
        # Measured on the CPU (one torch thread): max |batch - single| = 0.0, packaged and random weights.
        np.testing.assert_allclose(got.descriptors, one.descriptors, rtol=0, atol=1e-5)


@pytest.mark.parametrize("config", [PnvConfig(device="cpu"), RANDOM], ids=["packaged", "random"])
def test_a_batch_is_one_call_and_gives_each_view_its_single_features(whole_batches, config):
    d = Pnv(config)
    views = _views()
    with network_calls(d) as calls:
        many = d.extract_many(views)
    assert [c[0] for c in calls] == [4]
    _assert_same(many, views, d)
    assert [len(f) for f in many] == [144] * 4
    assert np.abs(many[0].descriptors - many[1].descriptors).max() > 0.02, "each view its own row of the batch"


def test_views_described_at_their_own_size_are_batched_by_size(whole_batches):
    d = Pnv(PnvConfig(weights="random", device="cpu", image_size=None))
    views = [_view(320, 192, 1), _view(256, 256, 2), _view(320, 192, 3), _view(160, 128, 4)]
    with network_calls(d) as calls:
        many = d.extract_many(views)
    assert [c[0] for c in calls] == [2, 1, 1]  # groups in the order of their first view
    assert [len(f) for f in many] == [16 * 8, 12 * 12, 16 * 8, 6 * 4]
    _assert_same(many, views, d)


def test_a_view_too_small_fails_the_batch_before_the_network_runs(whole_batches):
    d = Pnv(PnvConfig(weights="random", device="cpu", image_size=None))
    with network_calls(d) as calls, pytest.raises(InputError, match="a 64x64 view is too small"):
        d.extract_many([make_view(seed=1), _view(64, 64, 2)])
    assert calls == []


def test_on_the_cpu_each_view_is_its_own_call():
    d = Pnv(RANDOM)
    with network_calls(d) as calls:
        d.extract_many(_views()[:3])
    assert [c[0] for c in calls] == [1, 1, 1]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_on_cuda_a_batch_is_one_call_and_agrees_with_single_views_and_the_cpu():
    d = Pnv(PnvConfig(device="cuda"))
    views = _views()
    with network_calls(d) as calls:
        many = d.extract_many(views)
    assert [c[0] for c in calls] == [4]
    cpu = Pnv(PnvConfig(device="cpu"))
    for view, got in zip(views, many, strict=True):
        # cuDNN may pick other (TF32) kernels for another batch size: rounding in the convolutions only.
        np.testing.assert_allclose(got.descriptors, d.extract(view).descriptors, rtol=0, atol=1e-3)
        np.testing.assert_allclose(got.descriptors, cpu.extract(view).descriptors, rtol=0, atol=1e-3)
