"""Layout fill: what no source saw, drawn as the room's floor, walls and ceiling, in a room whose truth is known."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ssga_synthesizer_depth_warp.layout import _fold, estimate_layout
from ssga_synthesizer_depth_warp.plugin import DepthWarp, DepthWarpConfig

from ssga_core import Camera, Pose, View

CEILING = 2.6
HALF = 2.5  # the room spans [-HALF, HALF] along x and y
FLOOR, WALL, CEIL = 0, 1, 2
# Each surface's colour is strongest in the channel of its own index: red floor, green walls, blue ceiling.
COLOURS = np.array([[200, 40, 40], [40, 200, 40], [40, 40, 200]], dtype=np.uint8)


def render_room(pose: Pose, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A box room seen from ``pose``: colour, planar depth and the surface of every pixel, by ray casting."""
    uv = camera.pixel_grid().reshape(-1, 2)
    f = camera.focal_px
    cx, cy = camera.principal_point
    rays = np.stack([(uv[:, 0] - cx) / f, (uv[:, 1] - cy) / f, np.ones(len(uv))], 1) @ pose.rotation().T
    o = pose.position
    with np.errstate(divide="ignore", invalid="ignore"):
        floor = np.where(rays[:, 2] < 0, -o[2] / rays[:, 2], np.inf)
        ceiling = np.where(rays[:, 2] > 0, (CEILING - o[2]) / rays[:, 2], np.inf)
        walls = np.stack([(s * HALF - o[a]) / rays[:, a] for a in (0, 1) for s in (-1, 1)])
    wall = np.where(walls > 0, walls, np.inf).min(0)
    t = np.stack([floor, wall, ceiling])  # in the order FLOOR, WALL, CEIL
    surface = t.argmin(0)
    depth = t.min(0).astype(np.float32)  # planar: the rays have unit z in the camera
    rgb = COLOURS[surface]
    # Stripes on the walls and the floor, so a texture has something to continue.
    hit = o + depth[:, None] * rays
    stripes = (np.floor(hit[:, 0] * 4) + np.floor(hit[:, 1] * 4)) % 2 == 0
    rgb = np.where(stripes[:, None], rgb, rgb // 2)
    h, w = camera.shape
    return rgb.reshape(h, w, 3).astype(np.uint8), depth.reshape(h, w), surface.reshape(h, w)


def room_view(pose: Pose, camera: Camera) -> View:
    rgb, depth, _ = render_room(pose, camera)
    return View(rgb=rgb, pose=pose, camera=camera, depth=depth)


CAMERA = Camera(width=96, height=96, hfov_deg=90.0)
SOURCE = Pose(0.3, -0.2, 0.0)


def test_the_room_is_found_from_the_sources_points():
    view = room_view(SOURCE, CAMERA)
    points = view.pose.to_world(view.camera.unproject(view.depth)).reshape(-1, 3)
    layout = estimate_layout(points, Pose(0.0, 0.0, math.pi), wall_band=0.45)
    assert layout is not None
    assert layout.ceiling == pytest.approx(CEILING, abs=0.02)
    # The wall it saw (x = HALF, straight ahead of the source) is where it is.
    ahead = layout.wall_distance[len(layout.wall_distance) // 2]  # bearing 0: +x
    assert ahead == pytest.approx(HALF, abs=0.05)


def test_a_view_turned_away_from_the_source_is_drawn_as_the_room():
    """Turned 180 degrees, the target sees nothing the source saw: without layout it is all holes, with it the
    floor, walls and ceiling fall where the room's truly are, in their own colours."""
    source = room_view(SOURCE, CAMERA)
    target = Pose(0.0, 0.1, math.pi)
    _, true_depth, true_surface = render_room(target, CAMERA)
    plain = DepthWarp().synthesize(source, target).view
    assert plain.valid_depth().mean() < 0.05
    layout = DepthWarp(DepthWarpConfig(fill_unseen="layout")).synthesize(source, target).view
    assert layout.valid_depth().mean() > 0.99
    # Each filled pixel's colour is its surface's (either shade of its stripes).
    hue = np.argmax(layout.rgb.astype(int), axis=2)
    assert (hue == true_surface).mean() > 0.9
    # The unseen wall behind the source is placed by interpolation around the room: depth within 25%.
    relative = np.abs(layout.depth - true_depth) / true_depth
    assert np.median(relative) < 0.25


def test_without_a_seen_ceiling_nothing_is_guessed():
    source = room_view(SOURCE, CAMERA)
    low = np.where(render_room(SOURCE, CAMERA)[2] == CEIL, 0.0, source.depth).astype(np.float32)
    no_ceiling = View(rgb=source.rgb, pose=source.pose, camera=source.camera, depth=low)
    target = Pose(0.0, 0.1, math.pi)
    plain = DepthWarp().synthesize(no_ceiling, target).view
    layout = DepthWarp(DepthWarpConfig(fill_unseen="layout")).synthesize(no_ceiling, target).view
    np.testing.assert_array_equal(layout.rgb, plain.rgb)
    np.testing.assert_array_equal(layout.depth, plain.depth)


def test_what_a_source_saw_is_left_as_warped():
    source = room_view(SOURCE, CAMERA)
    target = Pose(0.2, -0.1, math.radians(50))
    plain = DepthWarp().synthesize(source, target)
    layout = DepthWarp(DepthWarpConfig(fill_unseen="layout")).synthesize(source, target)
    drawn = plain.view.valid_depth()
    assert 0.2 < drawn.mean() < 0.95
    np.testing.assert_array_equal(layout.view.rgb[drawn], plain.view.rgb[drawn])
    np.testing.assert_array_equal(layout.target_uv, plain.target_uv)


def test_heights_fold_back_and_forth_into_the_band():
    z = np.array([2.0, 2.2, 2.5, 2.6, 2.9, 3.2])
    folded = _fold(z, 2.2, 2.5)
    np.testing.assert_allclose(folded, [2.4, 2.2, 2.5, 2.4, 2.3, 2.4], atol=1e-9)
