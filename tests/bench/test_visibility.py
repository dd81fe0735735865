"""Bird's-eye visibility and view overlap, on hand-worked floor plans."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from ssga_core import Pose
from ssga_bench.visibility import cast_rays, occluder_segments, sees, view_overlap, visibility_polygon

# A wall 0.1 m thick along x = 3 .. 3.1, from y = -10 to 10.
WALL = shapely.box(3.0, -10.0, 3.1, 10.0)
SEGMENTS = occluder_segments(WALL)


def rays(pose: Pose, n: int = 91, max_range: float = 10.0) -> np.ndarray:
    return cast_rays(np.array([[pose.x, pose.y]]), np.array([pose.yaw]), 90.0, SEGMENTS, max_range, n)[0]


def test_rays_stop_at_the_wall():
    d = rays(Pose(0, 0, 0))
    assert d[45] == pytest.approx(3.0)  # straight ahead
    assert d[0] == pytest.approx(3.0 / math.cos(math.radians(45)))  # 45 degrees to the right


def test_rays_away_from_the_wall_reach_max_range():
    np.testing.assert_allclose(rays(Pose(0, 0, math.pi), max_range=7.5), 7.5)


def test_visibility_polygon_of_a_camera_facing_a_wall_is_a_triangle_of_known_area():
    poly = visibility_polygon(Pose(0, 0, 0), 90.0, rays(Pose(0, 0, 0), n=181))
    assert poly.area == pytest.approx(9.0, rel=1e-3)  # base 6 m at x = 3, height 3 m


def test_vo_of_a_view_with_itself_is_100():
    pose = Pose(0.5, 0.3, 0.4)
    poly = visibility_polygon(pose, 90.0, rays(pose))
    assert view_overlap(poly, poly) == pytest.approx(100.0)


def test_vo_of_opposite_views_behind_a_wall_is_0():
    a, b = Pose(0, 0, 0), Pose(6, 0, math.pi)  # both face the wall, from either side
    pa = visibility_polygon(a, 90.0, rays(a))
    pb = visibility_polygon(b, 90.0, rays(b))
    assert view_overlap(pa, pb) == 0.0


def test_vo_of_half_overlapping_views():
    # Facing the wall from 3 m: each sees a 6 m base; shifting 3 m sideways halves the overlap of bases.
    a, b = Pose(0, 0, 0), Pose(0, 3, 0)
    pa = visibility_polygon(a, 90.0, rays(a, n=181))
    pb = visibility_polygon(b, 90.0, rays(b, n=181))
    # Intersection: triangle with base 3 at x = 3 and apex at x = 1.5 -> 2.25 m2; union 18 - 2.25.
    assert view_overlap(pa, pb) == pytest.approx(100 * 2.25 / 15.75, rel=1e-2)


def test_sees_points_in_the_cone_not_behind_walls_or_outside_the_fov():
    pose = Pose(0, 0, 0)
    d = rays(pose)[None]
    points = np.array([[2.0, 0.0], [2.0, 1.9], [2.0, 2.1], [4.0, 0.0], [-1.0, 0.0]])
    got = sees(np.array([[0.0, 0.0]]), np.array([0.0]), d, 90.0, points)[0]
    np.testing.assert_array_equal(got, [True, True, False, False, False])


def test_occluder_segments_include_holes():
    ring = shapely.box(0, 0, 10, 10).difference(shapely.box(1, 1, 9, 9))
    assert len(occluder_segments(ring)) == 8
