"""Camera and pose conventions (stated once in ssga_core.geometry)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ssga_core import Camera, InputError, Pose


def test_habitat_defaults_give_f_128_and_centred_principal_point():
    cam = Camera()
    assert (cam.width, cam.height, cam.hfov_deg) == (256, 256, 90.0)
    assert cam.focal_px == pytest.approx(128.0)
    assert cam.principal_point == (127.5, 127.5)
    np.testing.assert_allclose(cam.K, [[128, 0, 127.5], [0, 128, 127.5], [0, 0, 1]])


def test_image_edges_are_at_half_the_field_of_view():
    cam = Camera()
    # The left edge of pixel 0 (u = -0.5) is 45 degrees left of the axis at hfov 90.
    uv, _ = cam.project(np.array([[-1.0, 0.0, 1.0]]))
    assert uv[0, 0] == pytest.approx(-0.5)
    uv, _ = cam.project(np.array([[1.0, 1.0, 1.0]]))
    np.testing.assert_allclose(uv[0], [255.5, 255.5])


def test_unproject_inverts_project_with_planar_depth():
    cam = Camera(width=320, height=240, hfov_deg=70)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-2, -1, 0.5], [2, 1, 8], size=(50, 3))
    uv, z = cam.project(pts)
    np.testing.assert_allclose(z, pts[:, 2])
    np.testing.assert_allclose(cam.unproject(z, uv), pts, atol=1e-4)


def test_points_behind_the_camera_have_no_pixel():
    uv, _ = Camera().project(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]))
    assert np.isnan(uv).all()
    assert not Camera().contains(uv).any()


@pytest.mark.parametrize("kwargs", [{"width": 0}, {"hfov_deg": 180}, {"hfov_deg": 0}])
def test_bad_cameras_are_rejected(kwargs):
    with pytest.raises(InputError, match="Camera"):
        Camera(**kwargs)


def test_yaw_zero_looks_along_x_and_down_is_minus_z():
    pose = Pose(1.0, 2.0, 0.0, height=1.5)
    np.testing.assert_allclose(pose.forward, [1, 0, 0], atol=1e-12)
    ahead = pose.to_camera(np.array([[4.0, 2.0, 1.5]]))[0]
    np.testing.assert_allclose(ahead, [0, 0, 3], atol=1e-12)
    # World +y is to the camera's left at yaw 0, and up is camera -y.
    left_up = pose.to_camera(np.array([[4.0, 3.0, 2.5]]))[0]
    assert left_up[0] < 0 and left_up[1] < 0


def test_a_point_left_of_the_camera_lands_in_the_left_half_of_the_image():
    pose = Pose(0.0, 0.0, math.pi / 2)  # looking along +y; -x is to the left
    uv, _ = Camera().project(pose.to_camera(np.array([[-1.0, 3.0, 1.5]])))
    assert uv[0, 0] < 127.5
    assert uv[0, 1] == pytest.approx(127.5)


def test_world_and_camera_transforms_are_inverse_rigid_motions():
    pose = Pose(-3.0, 0.5, 2.1, height=1.2)
    T = pose.world_from_camera()
    np.testing.assert_allclose(T @ pose.camera_from_world(), np.eye(4), atol=1e-12)
    R = T[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    pts = np.random.default_rng(1).normal(size=(10, 3))
    np.testing.assert_allclose(pose.to_world(pose.to_camera(pts)), pts, atol=1e-12)


def test_relative_transform_maps_between_cameras():
    a, b = Pose(0, 0, 0.3), Pose(1, -0.5, -0.4, height=1.6)
    p_a = np.array([0.2, -0.1, 3.0])
    p_b = (b.relative_to(a) @ np.append(p_a, 1.0))[:3]
    np.testing.assert_allclose(p_b, b.to_camera(a.to_world(p_a)), atol=1e-12)


@pytest.mark.parametrize("theta", [0.0, 0.7, -2.0, math.pi])
def test_habitat_pose_conversion(theta):
    # Habitat: y up, identity looks down -z; a turn of theta about +y.
    q = (math.cos(theta / 2), 0.0, math.sin(theta / 2), 0.0)
    pose = Pose.from_habitat(np.array([1.0, 1.5, -2.0]), np.array(q))
    assert (pose.x, pose.y, pose.height) == pytest.approx((1.0, 2.0, 1.5))
    # Habitat's forward (-z_h rotated by theta) expressed in ssga's frame (x, -z_h).
    fwd_h = np.array([-math.sin(theta), 0.0, -math.cos(theta)])
    np.testing.assert_allclose(pose.forward[:2], [fwd_h[0], -fwd_h[2]], atol=1e-12)


def test_habitat_pose_with_pitch_is_rejected():
    with pytest.raises(InputError, match="vertical axis"):
        Pose.from_habitat(np.zeros(3), np.array([0.9, 0.3, 0.0, 0.0]))
