"""Rendering one target from several views at once: one z-buffer, one hole filling."""

from __future__ import annotations

import numpy as np
import pytest
from ssga_synthesizer_depth_warp.plugin import DepthWarp, DepthWarpConfig
from ssga_synthesizer_depth_warp.warp import Source, forward_warp, forward_warp_many, surface_links

from ssga_core import InputError, Pose, View
from ssga_core.testing import make_view

RAW = DepthWarpConfig(footprint="square", fill_holes="none")
RED = (255, 0, 0)


def right_of(pose: Pose, metres: float) -> Pose:
    right = pose.rotation()[:, 0]
    return Pose(pose.x + metres * right[0], pose.y + metres * right[1], pose.yaw, pose.height)


def with_depth(view: View, depth: np.ndarray, rgb: np.ndarray | None = None) -> View:
    return View(rgb=view.rgb if rgb is None else rgb, pose=view.pose, camera=view.camera, depth=depth.astype(np.float32))


def halves() -> tuple[View, View]:
    """Two views of ssga's painted wall: one knows the depth of its left half only, the other of its right half."""
    view = make_view(seed=1)
    left, right = view.depth.copy(), view.depth.copy()
    left[:, 128:] = 0.0
    right[:, :128] = 0.0
    return with_depth(view, left), with_depth(view, right)


def test_two_views_that_each_see_half_fuse_into_one_image():
    a, b = halves()
    target = right_of(a.pose, 0.1)  # the wall moves 4.3 px left
    fused = DepthWarp(RAW).synthesize_from([a, b], target)
    alone = [DepthWarp(RAW).synthesize(v, target) for v in (a, b)]
    drawn = fused[0].view.depth > 0
    assert all((s.view.depth > 0).mean() <= 0.5 for s in alone)
    assert drawn[:, :250].all() and not drawn[:, 252:].any()  # all but the strip nobody saw
    # Each half is what that view renders alone, seam included: one surface, one z-buffer.
    np.testing.assert_array_equal(fused[0].view.rgb[:, :120], alone[0].view.rgb[:, :120])
    np.testing.assert_array_equal(fused[0].view.rgb[:, 126:250], alone[1].view.rgb[:, 126:250])
    # Each view's point map is its own; every point it knows lands on the front surface.
    for synthesis, view in zip(fused, (a, b), strict=True):
        inside = view.valid_depth() & view.camera.contains(synthesis.target_uv)
        assert (synthesis.visible == inside).all()


def test_a_point_behind_another_views_nearer_surface_is_not_visible():
    wall = make_view(seed=5)
    rgb, depth = wall.rgb.copy(), wall.depth.copy()
    rgb[96:160, 96:160] = RED
    depth[96:160, 96:160] = 1.5
    boxed = with_depth(wall, depth, rgb)  # a red box 1.5 m in front of the wall
    target = right_of(wall.pose, 0.3)  # the box lands on target columns 70..133, the wall moves 12.8 px
    box_seen, wall_seen = DepthWarp(RAW).synthesize_from([boxed, wall], target)
    np.testing.assert_array_equal(box_seen.view.rgb[97:159, 72:132], np.broadcast_to(RED, (62, 60, 3)))
    assert box_seen.visible[96:160, 96:160].all()
    # The wall view's points behind the box (source columns 85..144) are hidden by it,
    # those beside it are on the front surface, the wall.
    assert not wall_seen.visible[98:158, 86:143].any()
    assert wall_seen.visible[:, 20:80].all() and wall_seen.visible[:, 150:250].all()
    np.testing.assert_allclose(box_seen.view.depth[97:159, 72:132], 1.5, rtol=1e-6)


def test_one_view_gives_exactly_the_single_render():
    view = make_view(seed=3)
    target = Pose(view.pose.x + 0.4, view.pose.y - 0.2, view.pose.yaw + 0.3)
    synthesizer = DepthWarp(DepthWarpConfig(footprint="square"))
    (fused,) = synthesizer._synthesize_from([view], target)
    single = synthesizer.synthesize(view, target)
    for name in ("rgb", "depth"):
        np.testing.assert_array_equal(getattr(fused.view, name), getattr(single.view, name))
    np.testing.assert_array_equal(fused.target_uv, single.target_uv)
    np.testing.assert_array_equal(fused.visible, single.visible)


def test_all_views_share_one_synthetic_view_with_the_fused_depth():
    a, b = halves()
    target = right_of(a.pose, 0.1)
    syntheses = DepthWarp(DepthWarpConfig(footprint="square")).synthesize_from([a, b, a], target)
    assert len(syntheses) == 3 and all(s.view is syntheses[0].view for s in syntheses)
    fused = syntheses[0].view
    assert fused.synthetic and fused.pose == target and fused.camera == a.camera
    drawn = fused.depth > 0
    np.testing.assert_allclose(fused.depth[drawn], 3.0, rtol=1e-6)
    assert drawn.mean() > 0.95


def test_holes_are_filled_once_after_fusion():
    view = make_view(seed=2)
    a_depth, b_depth = view.depth.copy(), view.depth.copy()
    a_depth[:, 60:64] = 0.0  # a crack that only the other view covers
    a_depth[:, 100:104] = b_depth[:, 100:104] = 0.0  # and one that neither does
    fused = DepthWarp(DepthWarpConfig(footprint="square")).synthesize_from([with_depth(view, a_depth), with_depth(view, b_depth)], view.pose)[0].view
    np.testing.assert_array_equal(fused.rgb[:, 60:64], view.rgb[:, 60:64])  # drawn by b, not guessed
    assert (fused.depth[:, 60:64] == 3.0).all()
    assert (fused.depth[:, 100:104] == 0).all() and fused.rgb[:, 100:104].any(axis=-1).all()  # filled


def test_sources_of_different_sizes_share_one_z_buffer():
    f, size = 32.0, 64
    K = np.array([[f, 0.0, 31.5], [0.0, f, 31.5], [0.0, 0.0, 1.0]])
    K_narrow = np.array([[f, 0.0, 31.5 - 16], [0.0, f, 31.5], [0.0, 0.0, 1.0]])  # 48 columns: target columns 16..63
    rng = np.random.default_rng(0)
    wide = Source(rng.integers(0, 256, (size, size, 3), dtype=np.uint8), np.full((size, size), 3.0, np.float32), K, np.eye(4))
    narrow = Source(
        rng.integers(0, 256, (size, 48, 3), dtype=np.uint8), np.full((size, 48), 2.0, np.float32), K_narrow, np.eye(4)
    )
    w, n = forward_warp_many([wide, narrow], K, (size, size))
    assert w.target_uv.shape == (size, size, 2) and n.target_uv.shape == (size, 48, 2) and n.visible.shape == (size, 48)
    np.testing.assert_array_equal(w.rgb[:, 16:], narrow.rgb)  # nearer
    np.testing.assert_array_equal(w.rgb[:, :16], wide.rgb[:, :16])
    assert n.visible.all() and w.visible[:, :16].all() and not w.visible[:, 16:].any()
    assert w.rgb is n.rgb and w.covered.all()


def test_given_links_are_used_and_checked():
    view = make_view(seed=1, size=32)
    K = view.camera.K
    links = surface_links(view.depth)
    plain = forward_warp(view.rgb, view.depth, K, K, np.eye(4))
    (given,) = forward_warp_many([Source(view.rgb, view.depth, K, np.eye(4), links)], K, (32, 32))
    np.testing.assert_array_equal(plain.rgb, given.rgb)
    with pytest.raises(InputError, match="surface_links"):
        forward_warp_many([Source(view.rgb, view.depth, K, np.eye(4), links[:-1])], K, (32, 32))
    with pytest.raises(InputError, match="no source"):
        forward_warp_many([], K, (32, 32))
    with pytest.raises(InputError, match="source 1: image of uint16"):
        forward_warp_many(
            [Source(view.rgb, view.depth, K, np.eye(4)), Source(view.rgb.astype(np.uint16), view.depth, K, np.eye(4))],
            K,
            (32, 32),
        )
