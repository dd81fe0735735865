"""Beyond one pixel per point: surface links, adaptive footprints, depth edges, bilinear resampling."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from ssga_synthesizer_depth_warp import plugin
from ssga_synthesizer_depth_warp.plugin import DepthWarp, DepthWarpConfig
from ssga_synthesizer_depth_warp.warp import INTERIOR, LINKED_DOWN, LINKED_RIGHT, forward_warp, surface_links

from ssga_core import Camera, Pose, View
from ssga_core.testing import make_view

RAW = DepthWarpConfig(footprint="adaptive", fill_holes="none")
SQUARE_RAW = DepthWarpConfig(footprint="square", resample="nearest", fill_holes="none")
"""One pixel per point, its own colour: the 0.1 warp without hole filling."""
RED, GREY = (255, 0, 0), (128, 128, 128)


def right_of(pose: Pose, metres: float) -> Pose:
    right = pose.rotation()[:, 0]
    return Pose(pose.x + metres * right[0], pose.y + metres * right[1], pose.yaw, pose.height)


def ahead_of(pose: Pose, metres: float) -> Pose:
    return Pose(pose.x + metres * np.cos(pose.yaw), pose.y + metres * np.sin(pose.yaw), pose.yaw, pose.height)


def box_view(box_depth: float, wall: tuple[int, int, int] | None = None, box: slice = slice(112, 144)) -> View:
    """ssga's painted wall 3 m ahead (or a flat ``wall`` colour) with a red square at ``box_depth``."""
    view = make_view(seed=5)
    rgb, depth = view.rgb.copy(), view.depth.copy()
    if wall is not None:
        rgb[:] = wall
    rgb[box, box] = RED
    depth[box, box] = box_depth
    return View(rgb=rgb, pose=view.pose, camera=view.camera, depth=depth)


# --- surface links -----------------------------------------------------------------


def test_a_depth_edge_cuts_the_links_and_a_surface_keeps_them():
    depth = np.full((64, 64), 3.0, np.float32)
    depth[20:40, 20:40] = 2.0  # a box in front of the wall: 33% nearer
    links = surface_links(depth)
    assert not (links[20:40, 19] & LINKED_RIGHT).any() and not (links[20:40, 39] & LINKED_RIGHT).any()
    assert not (links[19, 20:40] & LINKED_DOWN).any() and not (links[39, 20:40] & LINKED_DOWN).any()
    assert (links[21:39, 21:39] == LINKED_RIGHT | LINKED_DOWN | INTERIOR).all()
    assert not (links[20:40, 20] & INTERIOR).any()  # the box's border: one neighbour is on the wall
    # The last column and row have no right or lower neighbour.
    assert not (links[:, -1] & LINKED_RIGHT).any() and not (links[-1] & LINKED_DOWN).any()


def test_a_floor_seen_at_a_grazing_angle_is_one_surface():
    # A level camera 1.5 m above a floor: depth 1.5 f / (v - cy) below the horizon, from
    # 96 m down to 1.5 m. Rows near the horizon differ by far more than depth_edge, but
    # inverse depth changes by the same step from row to row: a ramp, not an edge.
    camera = Camera(width=64, height=64)
    f, (_, cy) = camera.focal_px, camera.principal_point
    v = np.arange(64, dtype=np.float32)[:, None]
    depth = np.broadcast_to(np.where(v > cy, 1.5 * f / np.maximum(v - cy, 1e-3), 0.0), (64, 64)).astype(np.float32)
    links = surface_links(depth)
    assert depth[32, 0] / depth[33, 0] - 1 > 0.4  # the rows' depths differ by 40% and more
    assert (links[32:63] & LINKED_DOWN).all() and (links[32:, :-1] & LINKED_RIGHT).all()
    assert not links[:32].any()  # the sky: unknown depth links nothing


def test_unknown_depth_links_nothing():
    depth = np.full((16, 16), 2.0, np.float32)
    depth[5, 5] = 0.0
    depth[9, 9] = np.nan
    links = surface_links(depth, max_depth=50.0)
    for r, c in ((5, 5), (9, 9)):
        assert links[r, c] == 0
        assert not links[r, c - 1] & LINKED_RIGHT and not links[r - 1, c] & LINKED_DOWN
    assert surface_links(np.full((8, 8), 60.0, np.float32), max_depth=50.0).max() == 0


# --- adaptive footprints -----------------------------------------------------------


def test_moving_forward_leaves_no_crack():
    view = make_view(seed=2)
    syn = DepthWarp(RAW).synthesize(view, ahead_of(view.pose, 0.5))  # 1.2 x magnified
    assert (syn.view.depth > 0).all()
    np.testing.assert_allclose(syn.view.depth, 2.5, rtol=1e-6)
    assert (DepthWarp(SQUARE_RAW).synthesize(view, ahead_of(view.pose, 0.5)).view.depth == 0).mean() > 0.25


def test_a_surface_seen_five_times_closer_is_drawn_whole_and_read_where_each_pixel_maps():
    view = make_view(seed=4)
    syn = DepthWarp(RAW).synthesize(view, ahead_of(view.pose, 2.4))  # the wall is 0.6 m away: 5 x
    # The exact answer: target pixel p shows the source at c + (p - c) / 5, read bilinearly.
    c = np.array(view.camera.principal_point, dtype=np.float32)
    source = c + (view.camera.pixel_grid() - c) / 5.0
    expected = cv2.remap(view.rgb, source[..., 0], source[..., 1], cv2.INTER_LINEAR)
    assert (syn.view.depth > 0).all()
    error = np.abs(syn.view.rgb.astype(int) - expected)
    assert error.max() <= 2, error.max()
    # One pixel per point leaves 24 of every 25 pixels empty.
    square = DepthWarp(SQUARE_RAW).synthesize(view, ahead_of(view.pose, 2.4)).view
    assert 0.03 < (square.depth > 0).mean() < 0.05


def test_max_footprint_bounds_the_magnification_covered():
    view = make_view(seed=4)
    capped = DepthWarp(DepthWarpConfig(footprint="adaptive", fill_holes="none", max_footprint=4)).synthesize(
        view, ahead_of(view.pose, 2.4)
    )
    assert 0.2 < (capped.view.depth > 0).mean() < 0.9  # footprints reach 2 px of a drawn pixel, not 2.5


def test_a_nearer_surface_hides_what_is_behind_it_even_magnified():
    # A red box 1 m ahead of the painted wall: 1.5 m closer it is magnified 2 x (the wall
    # 1.2 x), so one pixel per point leaves three of every four of its pixels to the wall.
    view = box_view(box_depth=1.0)
    target = ahead_of(view.pose, 0.5)
    box = (slice(98, 158), slice(98, 158))  # its image in the target, about [95.5, 159.5)
    adaptive = DepthWarp(RAW).synthesize(view, target)
    assert (adaptive.view.rgb[box] == RED).all()
    np.testing.assert_allclose(adaptive.view.depth[box], 0.5, rtol=1e-5)
    square = DepthWarp(SQUARE_RAW).synthesize(view, target)
    assert (square.view.rgb[box] != RED).any(axis=-1).mean() > 0.3
    # Wall points that land behind the box (the wall pixel at source column 110 lands
    # at 106.5) are hidden; with one pixel per point they show through the cracks.
    behind = (slice(102, 152), slice(102, 112))
    assert not adaptive.visible[behind].any()
    assert square.visible[behind].mean() > 0.3


@pytest.mark.parametrize("splat", [1, 2])
def test_footprints_do_not_bridge_a_depth_edge(splat):
    # The box 1.5 m ahead of the wall, 0.3 m to the right: the 13 px of wall right of the
    # box were hidden from the source; they stay empty rather than a "rubber sheet"
    # stretched from the box to the wall.
    view = box_view(box_depth=1.5, box=slice(96, 160))
    target = right_of(view.pose, 0.3)
    syn = DepthWarp(DepthWarpConfig(footprint="adaptive", splat=splat, fill_holes="none")).synthesize(view, target)
    hole = (slice(100, 156), slice(136, 134 + 13 - splat))
    assert not syn.view.depth[hole].any()
    np.testing.assert_array_equal(syn.view.rgb[97:159, 72:132], np.broadcast_to(RED, (62, 60, 3)))
    # Were the box and the wall one surface, their points' footprints would span the gap.
    sheet = DepthWarp(DepthWarpConfig(footprint="adaptive", splat=splat, fill_holes="none", depth_edge=1.0)).synthesize(
        view, target
    )
    assert sheet.view.depth[hole].any()


# --- resampling ------------------------------------------------------------------------


def gradient_view(size: int = 64) -> View:
    """A wall 2 m ahead, its colour rising 3 levels per pixel to the right."""
    camera = Camera(width=size, height=size)
    ramp = (40 + 3 * np.arange(size))[None, :, None]
    rgb = np.broadcast_to(ramp, (size, size, 3)).astype(np.uint8)
    return View(rgb=rgb.copy(), pose=Pose(0.0, 0.0, 0.0), camera=camera, depth=np.full((size, size), 2.0, np.float32))


def test_bilinear_reads_between_pixels():
    view = gradient_view()
    # f = 32 px: 0.34375 m to the left shifts the wall 5.5 px right, between two pixels.
    target = right_of(view.pose, -0.34375)
    inner = (slice(2, -2), slice(8, -2))
    expected = (40 + 3 * (np.arange(64) - 5.5))[None, 8:-2]  # the source half a pixel off
    bilinear = DepthWarp(RAW).synthesize(view, target).view.rgb[inner][..., 0].astype(float)
    nearest = DepthWarp(SQUARE_RAW).synthesize(view, target).view.rgb[inner]
    assert np.abs(bilinear - expected).max() <= 0.6
    assert np.abs(nearest[..., 0].astype(float) - expected).min() >= 1.4  # a whole 1.5 levels off


def test_small_holes_read_the_surface_where_they_map_back():
    # One pixel per point leaves a third of the pixels empty 1.2 x magnified; the hole
    # filling reads each where it maps back through its nearest point's frame.
    view = make_view(seed=4)
    target = ahead_of(view.pose, 0.5)
    c = np.array(view.camera.principal_point, dtype=np.float32)
    source = c + (view.camera.pixel_grid() - c) / 1.2
    expected = cv2.remap(view.rgb, source[..., 0], source[..., 1], cv2.INTER_LINEAR).astype(int)
    filled = DepthWarp(DepthWarpConfig(footprint="square")).synthesize(view, target).view
    assert (filled.depth == 0).mean() > 0.25  # they stay holes: depth unknown
    assert np.abs(filled.rgb[1:-1, 1:-1] - expected[1:-1, 1:-1]).max() <= 2
    copied = DepthWarp(DepthWarpConfig(footprint="square", resample="nearest")).synthesize(view, target).view
    assert np.abs(copied.rgb[1:-1, 1:-1] - expected[1:-1, 1:-1]).max() > 50  # a neighbour's colour, across edges


def test_bilinear_reads_never_mix_two_surfaces():
    view = box_view(box_depth=1.5, wall=GREY, box=slice(96, 160))
    syn = DepthWarp(RAW).synthesize(view, right_of(view.pose, 0.29))  # box 24.75 px left, wall 12.4
    rgb = syn.view.rgb.reshape(-1, 3)
    drawn = syn.view.depth.reshape(-1) > 0
    colours = {tuple(c) for c in np.unique(rgb[drawn], axis=0)}
    assert colours == {RED, GREY}


def test_other_image_types_fall_back_to_nearest():
    view = gradient_view()
    K = view.camera.K
    T = right_of(view.pose, -0.34375).relative_to(view.pose)
    ids = np.arange(64 * 64, dtype=np.int64).reshape(64, 64)  # remap cannot take int64
    warp = forward_warp(ids, view.depth, K, K, T)
    assert warp.rgb.dtype == np.int64
    assert np.isin(warp.rgb[warp.covered], ids).all()


# --- the plugin ---------------------------------------------------------------------------


def test_surface_links_are_computed_once_per_view(monkeypatch):
    calls = []

    def counting(*args, **kwargs):
        calls.append(1)
        return surface_links(*args, **kwargs)

    monkeypatch.setattr(plugin, "surface_links", counting)
    synthesizer = DepthWarp(DepthWarpConfig(footprint="square"))
    view, other = make_view(seed=1), make_view(seed=2)
    for dx in (0.1, 0.2, 0.3):
        synthesizer.synthesize(view, right_of(view.pose, dx))
    assert len(calls) == 1
    synthesizer.synthesize(other, other.pose)
    assert len(calls) == 2
    DepthWarp(DepthWarpConfig(footprint="square", resample="nearest")).synthesize(view, view.pose)
    assert len(calls) == 2  # one pixel per point and its own colour need no links


@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("step", [0.03, 0.1, 0.3])
def test_a_steep_ramp_stays_visible_where_its_own_points_land(axis, step):
    # Inverse depth grows by `step` of its base per pixel: every pixel is nearer than its
    # neighbour by more than depth_tolerance, yet one surface. Rendered at its own pose,
    # each point lands on its own pixel and must stay visible there, whatever a
    # neighbour's footprint reaches; the picture is the source's.
    n = 48
    K = np.array([[24.0, 0, 23.5], [0, 24.0, 23.5], [0, 0, 1]])
    inverse = 0.2 * (1 + step * np.arange(n, dtype=np.float32))
    depth = np.ascontiguousarray(np.broadcast_to(1 / (inverse[:, None] if axis == 0 else inverse[None, :]), (n, n)), np.float32)
    rgb = np.random.default_rng(1).integers(0, 256, (n, n, 3), dtype=np.uint8)
    square = forward_warp(rgb, depth, K, K, np.eye(4), footprint="square")
    adaptive = forward_warp(rgb, depth, K, K, np.eye(4), footprint="adaptive")
    assert square.visible.all()
    assert adaptive.visible.all()
    np.testing.assert_array_equal(adaptive.rgb, rgb)
    np.testing.assert_allclose(adaptive.depth, depth, rtol=1e-5)
