"""The point splatter: soft-radius alpha profile, z-buffer order, K nearest, gradients, and the geometry feeding it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from ssga_synthesizer_synsin.model import move_points
from ssga_synthesizer_synsin.splat import splat

from ssga_core import Camera, Pose


def _one(uv, z, feats, size=(12, 16), **kw):
    kw = {"radius": 2.5, "points_per_pixel": 8, **kw}
    t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))[None]
    return splat(t(uv), t(z), t(feats), size, **kw)


def _alpha(d2: np.ndarray, r: float, tau: float = 1.0) -> np.ndarray:
    return (1 - np.sqrt(np.clip(d2 / r**2, 1e-3, 1.0))) ** tau


@pytest.mark.parametrize("tau", [1.0, 2.0])
def test_a_single_point_splats_with_the_soft_radius_profile(tau):
    u, v, r = 7.3, 5.6, 2.5
    s = _one([[u, v]], [2.0], [[1.0, 3.0]], radius=r, tau=tau)
    rows, cols = np.mgrid[0:12, 0:16]
    d2 = (cols - u) ** 2 + (rows - v) ** 2
    expected = np.where(d2 < r * r, _alpha(d2, r, tau), 0.0)
    np.testing.assert_allclose(s.features[0, 0].numpy(), expected, atol=1e-6)
    np.testing.assert_allclose(s.features[0, 1].numpy(), 3 * expected, atol=1e-6)
    np.testing.assert_allclose(s.coverage[0, 0].numpy(), expected, atol=1e-6)
    assert (s.features[0, 0] > 0).sum() == 19  # the pixels whose centres lie within 2.5 px of (7.3, 5.6)
    # the front-most depth wherever the point reaches, 0 elsewhere; its own pixel is (7, 6)
    np.testing.assert_array_equal(s.depth[0].numpy(), np.where(d2 < r * r, 2.0, 0.0))
    assert s.nearest[0, 0] == 2.0
    # a point on a pixel centre: SynSin's clamp caps alpha at 1 - sqrt(1e-3)
    centred = _one([[4.0, 4.0]], [1.0], [[1.0]], radius=r)
    assert centred.features[0, 0, 4, 4] == pytest.approx(1 - math.sqrt(1e-3))


def test_the_nearer_of_two_points_at_one_pixel_dominates():
    a0 = 1 - math.sqrt(1e-3)
    for order in ([0, 1], [1, 0]):  # the input order does not matter, only the depths
        uv = np.array([[5.0, 4.0], [5.0, 4.0]])[order]
        z = np.array([1.0, 3.0])[order]
        f = np.array([[1.0, 0.0], [0.0, 1.0]])[order]
        s = _one(uv, z, f, radius=1.5)
        near, far = s.features[0, :, 4, 5].numpy()
        assert near == pytest.approx(a0) and far == pytest.approx(a0 * (1 - a0))  # front to back
        assert s.depth[0, 4, 5] == 1.0
        assert s.nearest[0].tolist() == [1.0, 1.0]
    # K = 1 keeps only the nearest point of each pixel
    s = _one([[5.0, 4.0], [5.0, 4.0]], [3.0, 1.0], [[0.0, 1.0], [1.0, 0.0]], radius=1.5, points_per_pixel=1)
    assert s.features[0, 1, 4, 5] == 0.0 and s.features[0, 0, 4, 5] == pytest.approx(a0)
    # a farther point next to a nearer one shows only where the nearer one does not reach
    s = _one([[5.0, 4.0], [6.0, 4.0]], [1.0, 3.0], [[1.0, 0.0], [0.0, 1.0]], radius=1.0)
    assert s.features[0, 1, 4, 6] == pytest.approx(a0)  # the near point is 1 px away: alpha 0 there


def test_points_behind_the_camera_unknown_or_masked_draw_nothing():
    uv = [[3.0, 3.0], [6.0, 6.0], [float("nan"), 2.0], [9.0, 9.0]]
    z = [-1.0, 0.0, 2.0, 2.0]
    f = [[1.0], [1.0], [1.0], [1.0]]
    s = _one(uv, z, f, mask=torch.tensor([[True, True, True, False]]))
    assert not s.features.any() and not s.coverage.any() and not s.depth.any()
    assert torch.isinf(s.nearest).all()
    off = _one([[-5.0, 3.0], [40.0, 3.0]], [1.0, 1.0], [[1.0], [1.0]])  # beyond the image's edges
    assert not off.features.any()


def test_gradients_flow_to_features_and_depth():
    torch.manual_seed(0)
    depth = torch.full((2, 1, 10, 12), 2.0, dtype=torch.float64)
    depth[:, :, 3:7, 4:8] = 1.0  # a box in front of a wall
    depth.requires_grad_()
    feats = torch.rand(2, 10 * 12, 4, dtype=torch.float64, requires_grad=True)
    K = torch.tensor([[6.0, 0, 5.5], [0, 6.0, 4.5], [0, 0, 1]], dtype=torch.float64)
    T = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    T[:, 0, 3] = torch.tensor([0.13, -0.21])  # sideways: points land between pixels
    uv, z = move_points(depth, K, T)
    s = splat(uv, z, feats, (10, 12), radius=1.5, points_per_pixel=8)
    weights = torch.rand_like(s.features)
    (s.features * weights).sum().backward()
    assert feats.grad is not None and feats.grad.abs().sum() > 0
    assert depth.grad is not None and depth.grad.abs().sum() > 0 and torch.isfinite(depth.grad).all()
    # the gradient is the true one (away from the alpha clamp's kinks)
    uv0 = (torch.rand(1, 6, 2, dtype=torch.float64) * torch.tensor([9.0, 7.0]) + 1.3).requires_grad_()
    z0 = torch.rand(1, 6, dtype=torch.float64) + 1.0
    f0 = torch.rand(1, 6, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: splat(a, z0, b, (10, 12), radius=1.7, points_per_pixel=4).features, (uv0, f0))


def test_moved_points_follow_the_core_geometry():
    camera = Camera(width=20, height=14, hfov_deg=75.0)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 5.0, camera.shape).astype(np.float32)
    source, target = Pose(0.0, 0.0, 0.3), Pose(0.4, -0.2, 0.6)
    T = target.relative_to(source)
    uv, z = move_points(torch.from_numpy(depth)[None, None].double(), torch.from_numpy(camera.K), torch.from_numpy(T)[None])
    expected_uv, expected_z = camera.project(camera.unproject(depth) @ T[:3, :3].T + T[:3, 3])
    finite = np.isfinite(expected_uv).all(-1).reshape(-1)
    np.testing.assert_allclose(uv[0].numpy()[finite], expected_uv.reshape(-1, 2)[finite], atol=1e-3)
    np.testing.assert_allclose(z[0].numpy(), expected_z.reshape(-1), atol=1e-4)
    assert np.isnan(uv[0].numpy()[~finite]).all()
