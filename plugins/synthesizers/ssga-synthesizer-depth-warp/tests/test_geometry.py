"""Warps whose result is known exactly: ssga's painted wall 3 m ahead, f = 128 px, moved and turned."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from ssga_synthesizer_depth_warp.plugin import DepthWarp, DepthWarpConfig
from ssga_synthesizer_depth_warp.warp import fill_holes, forward_warp

from ssga_core import Camera, InputError, Pose, View
from ssga_core.testing import make_view

RAW = DepthWarpConfig(footprint="square", fill_holes="none")
SQUARE_RAW = DepthWarpConfig(footprint="square", resample="nearest", fill_holes="none")
"""One pixel per point, its own colour: the 0.1 warp without hole filling."""


def right_of(pose: Pose, metres: float) -> Pose:
    right = pose.rotation()[:, 0]
    return Pose(pose.x + metres * right[0], pose.y + metres * right[1], pose.yaw, pose.height)


@pytest.mark.parametrize("splat", [1, 2, 3])
def test_same_pose_changes_nothing(splat):
    view = make_view(seed=3)
    syn = DepthWarp(DepthWarpConfig(footprint="square", splat=splat)).synthesize(view, view.pose)
    assert syn.visible.all()
    np.testing.assert_allclose(syn.target_uv, view.camera.pixel_grid(), atol=1e-3)
    np.testing.assert_array_equal(syn.view.rgb, view.rgb)
    np.testing.assert_allclose(syn.view.depth, view.depth, rtol=1e-6)
    assert syn.view.synthetic and syn.view.pose == view.pose and syn.view.camera == view.camera
    assert syn.view.rgb.dtype == np.uint8 and syn.view.depth.dtype == np.float32


def test_sideways_move_shifts_by_f_t_over_z():
    view = make_view(seed=1)  # wall at z = 3 m, f = 128 px
    t = 0.375  # 128 * 0.375 / 3 = 16 px
    syn = DepthWarp(RAW).synthesize(view, right_of(view.pose, t))
    shift = view.camera.focal_px * t / 3.0
    assert shift == pytest.approx(16.0)
    expected = view.camera.pixel_grid() - np.array([shift, 0.0], dtype=np.float32)
    np.testing.assert_allclose(syn.target_uv, expected, atol=1e-3)
    # Moving right moves the content left; the 16 columns on the right were never seen.
    np.testing.assert_array_equal(syn.view.rgb[:, :-16], view.rgb[:, 16:])
    assert not syn.view.rgb[:, -16:].any() and not syn.view.depth[:, -16:].any()
    np.testing.assert_allclose(syn.view.depth[:, :-16], 3.0, rtol=1e-6)
    assert syn.visible[:, 16:].all() and not syn.visible[:, :16].any()


def test_sideways_move_on_a_wide_image():
    camera = Camera(width=320, height=200, hfov_deg=90.0)  # f = 160 px
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (200, 320, 3), dtype=np.uint8)
    view = View(rgb=rgb, pose=Pose(1.0, 2.0, 0.7), camera=camera, depth=np.full((200, 320), 2.0, np.float32))
    syn = DepthWarp(RAW).synthesize(view, right_of(view.pose, -0.25))  # 0.25 m to the left: 20 px right
    np.testing.assert_allclose(syn.target_uv - camera.pixel_grid(), np.broadcast_to([20.0, 0.0], (200, 320, 2)), atol=1e-3)
    np.testing.assert_array_equal(syn.view.rgb[:, 20:], rgb[:, :-20])


def test_moving_forward_enlarges_about_the_centre():
    view = make_view(seed=2)
    ahead = Pose(view.pose.x + 0.5, view.pose.y, view.pose.yaw)  # yaw 0 looks along +x
    syn = DepthWarp(SQUARE_RAW).synthesize(view, ahead)
    c = np.array(view.camera.principal_point, dtype=np.float32)
    np.testing.assert_allclose(syn.target_uv - c, 1.2 * (view.camera.pixel_grid() - c), atol=1e-3)  # 3 m / 2.5 m
    drawn = syn.view.depth > 0
    np.testing.assert_allclose(syn.view.depth[drawn], 2.5, rtol=1e-6)
    # A single-pixel splat leaves cracks: 1 / 1.2^2 of the pixels get a point.
    assert abs(drawn.mean() - 1 / 1.44) < 0.01
    # Points that leave the image are kept in the point map but are not visible.
    outside = ~view.camera.contains(syn.target_uv)
    assert outside.any() and not syn.visible[outside].any() and syn.visible[~outside].all()


def test_moving_back_keeps_every_point_of_the_surface_visible():
    view = make_view(seed=2)
    back = Pose(view.pose.x - 1.0, view.pose.y, view.pose.yaw)  # the wall is now 4 m away
    syn = DepthWarp(DepthWarpConfig(footprint="square")).synthesize(view, back)
    c = np.array(view.camera.principal_point, dtype=np.float32)
    np.testing.assert_allclose(syn.target_uv - c, 0.75 * (view.camera.pixel_grid() - c), atol=1e-3)
    # Up to four points share a target pixel; all of them are on the front surface.
    assert syn.visible.all()
    drawn = syn.view.depth > 0
    assert drawn[40:216, 40:216].all() and not drawn[:30].any() and not drawn[:, -30:].any()
    # The 32 px border the source never saw is too wide to fill.
    assert not syn.view.rgb[:30].any()


def test_larger_splats_and_hole_filling_close_the_cracks():
    view = make_view(seed=2)
    ahead = Pose(view.pose.x + 0.5, view.pose.y, view.pose.yaw)
    raw = DepthWarp(SQUARE_RAW).synthesize(view, ahead).view
    assert (raw.depth == 0).mean() > 0.25
    for splat in (2, 3):
        config = DepthWarpConfig(footprint="square", splat=splat, resample="nearest", fill_holes="none")
        assert (DepthWarp(config).synthesize(view, ahead).view.depth > 0).all()
    for fill in ("nearest", "inpaint"):
        filled = DepthWarp(DepthWarpConfig(footprint="square", fill_holes=fill, resample="nearest")).synthesize(view, ahead).view
        drawn = raw.depth > 0
        np.testing.assert_array_equal(filled.rgb[drawn], raw.rgb[drawn])
        np.testing.assert_array_equal(filled.depth, raw.depth)  # filled pixels keep unknown depth
        # Every crack is filled, with a colour within (nearest) or about (inpaint) the range
        # of those drawn around it.
        lo = cv2.erode(np.where(drawn[..., None], raw.rgb, 255).astype(np.uint8), np.ones((7, 7), np.uint8)).astype(int)
        hi = cv2.dilate(raw.rgb, np.ones((7, 7), np.uint8)).astype(int)
        slack = 0 if fill == "nearest" else 12  # Telea extrapolates gradients
        assert ((filled.rgb >= lo - slack) & (filled.rgb <= hi + slack)).all(), fill
        assert (filled.rgb[~drawn] != 0).any(axis=-1).all(), fill


@pytest.mark.parametrize("yaw", [0.1, -0.25])
def test_turning_moves_content_the_expected_way(yaw):
    view = make_view(seed=4)
    turned = Pose(view.pose.x, view.pose.y, view.pose.yaw + yaw)
    syn = DepthWarp(RAW).synthesize(view, turned)
    f = view.camera.focal_px
    cx, cy = view.camera.principal_point
    grid = view.camera.pixel_grid()
    a = (grid[..., 0] - cx) / f
    # Turning left by yaw (counter-clockwise seen from above) rotates the scene right in the
    # image: a ray at x/z = a ends up at (a cos + sin) / (cos - a sin).
    denom = math.cos(yaw) - a * math.sin(yaw)
    expected_u = cx + f * (a * math.cos(yaw) + math.sin(yaw)) / denom
    expected_v = cy + (grid[..., 1] - cy) / denom
    np.testing.assert_allclose(syn.target_uv[..., 0], expected_u, atol=2e-3)
    np.testing.assert_allclose(syn.target_uv[..., 1], expected_v, atol=2e-3)
    centre_shift = float(np.interp(cx, grid[0, :, 0], syn.target_uv[128, :, 0]) - cx)
    assert centre_shift == pytest.approx(f * math.tan(yaw), abs=0.01)
    assert np.sign(np.median(syn.target_uv[..., 0] - grid[..., 0])) == np.sign(yaw)


def occlusion_view() -> View:
    """A red 64 x 64 px box 1.5 m ahead of a wall 3 m ahead."""
    view = make_view(seed=5)
    rgb, depth = view.rgb.copy(), view.depth.copy()
    rgb[96:160, 96:160] = (255, 0, 0)
    depth[96:160, 96:160] = 1.5
    return View(rgb=rgb, pose=view.pose, camera=view.camera, depth=depth)


@pytest.mark.parametrize("splat", [1, 2])
def test_near_object_hides_the_wall_behind_it(splat):
    view = occlusion_view()
    syn = DepthWarp(DepthWarpConfig(footprint="square", splat=splat, fill_holes="none")).synthesize(view, right_of(view.pose, 0.3))
    # The wall moves 12.8 px left, the box 25.6 px: the box lands on target columns 70..133
    # and covers the wall from source columns 83..95.
    assert not syn.visible[96:160, 84:95].any()
    assert syn.visible[96:160, 20:80].all() and syn.visible[96:160, 96:160].all()
    np.testing.assert_array_equal(syn.view.rgb[97:159, 72:132], np.broadcast_to((255, 0, 0), (62, 60, 3)))
    np.testing.assert_allclose(syn.view.depth[97:159, 72:132], 1.5, rtol=1e-6)
    # Right of the box, the wall it hid in the source is a hole (13 px wide).
    assert not syn.view.depth[100:156, 136 : 134 + 13 - splat].any()
    # The hidden wall points still have their place in the point map.
    np.testing.assert_allclose(syn.target_uv[96:160, 84:95, 0], np.broadcast_to(np.arange(84, 95) - 12.8, (64, 11)), atol=1e-3)


def test_points_behind_the_target_camera_are_nan():
    view = make_view()
    beyond = Pose(view.pose.x + 4.0, view.pose.y, view.pose.yaw)  # past the wall 3 m ahead
    syn = DepthWarp(DepthWarpConfig(footprint="square")).synthesize(view, beyond)
    assert np.isnan(syn.target_uv).all() and not syn.visible.any()
    assert not syn.view.rgb.any() and not syn.view.depth.any()


def test_unknown_and_too_far_depths_are_skipped():
    view = make_view()
    depth = view.depth.copy()
    depth[:10] = 0.0
    depth[10:20] = np.nan
    depth[20:30] = np.inf
    depth[30:40] = 80.0  # beyond max_depth = 50 m
    holed = View(rgb=view.rgb, pose=view.pose, camera=view.camera, depth=depth)
    syn = DepthWarp(RAW).synthesize(holed, holed.pose)
    assert np.isnan(syn.target_uv[:40]).all() and not syn.visible[:40].any()
    assert not syn.view.rgb[:40].any() and syn.visible[40:].all()
    farther = DepthWarp(DepthWarpConfig(footprint="square", max_depth=100.0, fill_holes="none")).synthesize(holed, holed.pose)
    assert farther.visible[30:40].all()


def test_nearest_fill_copies_a_nearest_drawn_pixel():
    rng = np.random.default_rng(0)
    image = rng.integers(1, 256, (40, 50, 3), dtype=np.uint8)
    covered = rng.random((40, 50)) > 0.3
    out = fill_holes(np.where(covered[..., None], image, 0).astype(np.uint8), covered, "nearest", max_hole=8)
    cv, cu = np.nonzero(covered)
    for v, u in zip(*np.nonzero(~covered), strict=True):
        d = np.hypot(cv - v, cu - u)
        # OpenCV's 5 x 5 distance mask approximates L2 to within a few percent.
        candidates = d <= d.min() * 1.05 + 1e-6
        assert any((out[v, u] == image[cv[k], cu[k]]).all() for k in np.flatnonzero(candidates)), (v, u)


def test_large_holes_stay_empty():
    covered = np.ones((64, 64), bool)
    covered[10:12, 5:60] = False  # a 2 px crack
    covered[30:50, 20:40] = False  # a 20 px hole
    image = np.full((64, 64, 3), 200, np.uint8)
    image[~covered] = 0
    out = fill_holes(image, covered, "nearest", max_hole=8)
    assert (out[10:12, 5:60] == 200).all()
    assert not out[32:48, 22:38].any()


def test_bad_inputs_are_refused():
    view = make_view(size=32)
    K = view.camera.K
    with pytest.raises(InputError, match="does not match depth"):
        forward_warp(view.rgb, view.depth[:-1], K, K, np.eye(4))
    with pytest.raises(InputError, match="pinhole intrinsics"):
        forward_warp(view.rgb, view.depth, np.eye(4), K, np.eye(4))
    with pytest.raises(InputError, match="4 x 4 transform"):
        forward_warp(view.rgb, view.depth, K, K, np.eye(3))
    with pytest.raises(InputError, match="splat"):
        forward_warp(view.rgb, view.depth, K, K, np.eye(4), splat=0)
    with pytest.raises(InputError, match="unknown method 'blur'"):
        fill_holes(view.rgb, np.ones((32, 32), bool), "blur")  # type: ignore[arg-type]


def test_any_target_size_and_channels():
    view = make_view(size=64)
    K = view.camera.K
    K2 = np.array([[32.0, 0.0, 63.5], [0.0, 32.0, 31.5], [0.0, 0.0, 1.0]])  # a 128 x 64 target, same focal length
    gray = view.rgb[..., 0]
    warp = forward_warp(gray, view.depth, K, K2, np.eye(4), out_shape=(64, 128))
    assert warp.rgb.shape == (64, 128) and warp.rgb.dtype == np.uint8
    assert warp.target_uv.shape == (64, 64, 2) and warp.visible.shape == (64, 64)
    np.testing.assert_allclose(warp.target_uv[..., 0], view.camera.pixel_grid()[..., 0] + 32.0, atol=1e-3)
    np.testing.assert_array_equal(warp.rgb[:, 32:96], gray)
