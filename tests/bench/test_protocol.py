"""The benchmark protocol on hand-worked floor plans."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from ssga_core import Camera, InputError
from ssga_bench.protocol import FULL_REACH, Grid, Protocol, ProtocolConfig, level_of, suggest
from ssga_bench.visibility import view_overlap
from ssga_bench.workspace import FloorPlan


def two_rooms() -> FloorPlan:
    """A 12 x 8 m flat cut by a wall at x = 6 with a doorway from y = 3 to 4.5."""
    outer = shapely.box(-0.1, -0.1, 12.1, 8.1).difference(shapely.box(0, 0, 12, 8))
    inner = shapely.union(shapely.box(6, 0, 6.1, 3), shapely.box(6, 4.5, 6.1, 8))
    occluders = shapely.union(outer, inner)
    return FloorPlan(free=shapely.box(0, 0, 12, 8).difference(occluders.buffer(0.25)), occluders=occluders)


@pytest.fixture(scope="module")
def protocol() -> Protocol:
    return Protocol(two_rooms(), Camera(), ProtocolConfig(cells=4, test_per_class=3, seed=1))


@pytest.fixture(scope="module")
def plan(protocol):
    return protocol.plan("two-rooms")


def test_grid_is_aligned_to_multiples_of_the_cell_size():
    grid = Grid.covering((-0.1, -0.1, 12.1, 8.1), 2.0)
    assert (grid.x0, grid.y0, grid.nx, grid.ny) == (-2.0, -2.0, 8, 6)
    assert grid.box(grid.nx + 1) == (0.0, 0.0, 2.0, 2.0)
    np.testing.assert_allclose(grid.centroids()[grid.nx + 1], [1.0, 1.0])


def test_orientation_bins_are_centred_on_multiples_of_30_degrees(protocol):
    deg = np.radians([0, 14.9, 15.1, 90, 345.1, -14])
    np.testing.assert_array_equal(protocol.orientation_of(deg), [0, 0, 1, 3, 0, 0])


def test_a_view_belongs_to_the_nearest_centroid_in_its_cone(protocol):
    grid = protocol.grid
    cell = lambda i, j: j * grid.nx + i  # noqa: E731 - centroid (x0 + (i + .5) * 2, y0 + (j + .5) * 2)
    # At (1.5, 1.0) looking along +x: centroids (3, 1), (5, 1) and beyond are in the cone; (3, 1) is nearest.
    assert protocol.assign(np.array([[1.5, 1.0]]), np.array([0.0]))[0] == cell(2, 1)
    # At (1.5, 1.0) looking along -x the centroid (1, 1) is 0.5 m ahead, in front of the wall at x = 0...
    assert protocol.assign(np.array([[1.5, 1.0]]), np.array([math.pi]))[0] == cell(1, 1)
    # ...but from (0.5, 2.0) nothing is: the next centroids are behind that wall.
    assert protocol.assign(np.array([[0.5, 2.0]]), np.array([math.pi]))[0] == -1
    # At (5, 1) looking along +x, the centroid (7, 1) is behind the wall at x = 6.
    assert protocol.assign(np.array([[5.0, 1.0]]), np.array([0.0]))[0] == -1
    # Through the doorway (y = 3..4.5) the centroid (7, 3) is visible from (5, 3.6).
    assert protocol.assign(np.array([[5.0, 3.6]]), np.array([-0.2]))[0] == cell(4, 2)


def test_canonical_viewpoints_belong_to_their_class(protocol, plan):
    for s in plan.split("train") + plan.split("target"):
        assert protocol.is_free(np.array([s.pose.x, s.pose.y]))[0]
        assert protocol.assign(np.array([[s.pose.x, s.pose.y]]), np.array([s.pose.yaw]))[0] == s.cell
        assert protocol.orientation_of(s.pose.yaw) == s.orientation


def test_one_real_image_per_cell_and_targets_for_the_other_classes(plan):
    assert plan.num_classes == 48
    train, targets = plan.split("train"), plan.split("target")
    assert len(train) == 4 and len({s.cell for s in train}) == 4
    assert len(targets) == 44
    assert {s.place for s in train} | {s.place for s in targets} == set(range(48))


def test_a_validation_quota_per_level_draws_more_hard_views_and_leaves_the_test_draw_as_it_was(protocol, plan):
    config = ProtocolConfig(cells=4, test_per_class=3, val_per_class=1, seed=1)
    plain = Protocol(two_rooms(), Camera(), config).plan("two-rooms")
    quota = Protocol(two_rooms(), Camera(), config.model_copy(update={"val_per_level": 12})).plan("two-rooms")
    assert [s.pose for s in quota.split("test")] == [s.pose for s in plain.split("test")] == [s.pose for s in plan.split("test")]
    before, after = (np.bincount([s.level for s in p.split("val")], minlength=4)[1:] for p in (plain, quota))
    # Best effort, as for test views: L2 reaches its quota, L3 gets what twice the share per class allows.
    assert after[1] >= 12 > before[1] and after[2] > before[2], f"more L2/L3 validation views: {before} -> {after}"
    per_class = np.bincount([s.place for s in quota.split("val")], minlength=48)
    assert per_class.min() >= 1 and per_class.max() <= 2, "each class: its share, then at most twice it"


def test_test_views_fill_every_class_and_belong_to_it(protocol, plan):
    tests = plan.split("test")
    assert np.bincount([s.place for s in tests], minlength=48).tolist() == [3] * 48
    xy = np.array([[s.pose.x, s.pose.y] for s in tests])
    yaw = np.array([s.pose.yaw for s in tests])
    np.testing.assert_array_equal(protocol.assign(xy, yaw), [s.cell for s in tests])
    np.testing.assert_array_equal(protocol.orientation_of(yaw), [s.orientation for s in tests])


def test_vo_and_levels_of_test_views(protocol, plan):
    training = {s.place: s.pose for s in plan.split("train") + plan.split("target")}
    for s in plan.split("test")[:20]:
        vo = view_overlap(protocol.polygon(s.pose), protocol.polygon(training[s.place]))
        assert s.vo == pytest.approx(vo, abs=1e-6)
        assert s.level == level_of(s.vo)
        assert 0.0 <= s.vo_landmark <= 100.0


@pytest.mark.parametrize(("vo", "level"), [(100, 1), (60.01, 1), (60, 2), (30.01, 2), (30, 3), (0, 3)])
def test_level_boundaries(vo, level):
    assert level_of(vo) == level


def test_plans_are_deterministic_and_seeded():
    a = Protocol(two_rooms(), Camera(), ProtocolConfig(cells=3, test_per_class=2, seed=5)).plan("x")
    b = Protocol(two_rooms(), Camera(), ProtocolConfig(cells=3, test_per_class=2, seed=5)).plan("x")
    c = Protocol(two_rooms(), Camera(), ProtocolConfig(cells=3, test_per_class=2, seed=6)).plan("x")
    assert a == b
    assert a.samples != c.samples


def test_too_many_cells_is_a_clear_error():
    with pytest.raises(InputError, match=r"only \d+ of its 48 cells of 2.0 m can be seen from all 12 headings, 40 wanted"):
        Protocol(two_rooms(), Camera(), ProtocolConfig(cells=40)).plan("two-rooms")


def test_landmark_levels_can_be_chosen():
    config = ProtocolConfig(cells=2, test_per_class=2, seed=2, level_reference="landmark")
    plan = Protocol(two_rooms(), Camera(), config).plan("x")
    assert all(s.level == level_of(s.vo_landmark) for s in plan.split("test"))


def narrow_room() -> FloorPlan:
    """A 6 x 3 m room whose free floor ends 0.25 m from its walls: cells of 1 m in rows at y = 0.5,
    1.5 and 2.5, the first and last 0.5 m from a wall."""
    occluders = shapely.box(-0.1, -0.1, 6.1, 3.1).difference(shapely.box(0, 0, 6, 3))
    return FloorPlan(free=shapely.box(0.25, 0.25, 5.75, 2.75), occluders=occluders)


def cell_at(protocol: Protocol, x: float, y: float) -> int:
    return int(np.flatnonzero(np.all(np.isclose(protocol.centroids, [x, y]), axis=1))[0])


def test_a_canonical_viewpoint_stands_at_the_farthest_free_step():
    protocol = Protocol(narrow_room(), Camera(), ProtocolConfig(cell_size=1.0, orientations=4))
    cell = cell_at(protocol, 2.5, 0.5)  # 0.5 m from the wall at y = 0
    found = protocol.canonical_viewpoints(cell, 1.5)
    steps = [step for _, step in found]  # type: ignore[misc]
    # Looking along +x or -x the full metre behind is free; looking away from the wall (+y) the
    # camera must stand between the wall and the centroid: free floor starts 0.25 m from the wall,
    # so 0.5 m and 0.25 m behind (y = 0 and 0.25) are not free, 0.125 m (y = 0.375) is.
    assert steps == [1.0, 0.125, 1.0, 1.0]
    pose, _ = found[1]  # type: ignore[misc]
    assert (pose.x, pose.y, pose.yaw) == pytest.approx((2.5, 0.375, math.pi / 2))


def test_cells_that_need_near_viewpoints_are_drawn_only_when_too_few_others():
    protocol = Protocol(narrow_room(), Camera(), ProtocolConfig(cell_size=1.0, cells=2, test_per_class=1))
    cells = protocol.free_cells()
    full = [c for c in cells if min(step for _, step in protocol.canonical_viewpoints(c, 1.5)) >= FULL_REACH]  # type: ignore[misc]
    near = [c for c in protocol.eligible_cells(cells, 1.5) if c not in full]
    assert full and near, "the room has both kinds"
    assert all(protocol.centroids[c][1] == 1.5 for c in full), "only the middle row has room behind every heading"
    for wanted in (len(full), len(full) + 1):
        config = ProtocolConfig(cell_size=1.0, cells=wanted, test_per_class=1)
        chosen = set(Protocol(narrow_room(), Camera(), config).plan("narrow").cells)
        assert set(full) <= chosen and len(chosen - set(full)) == wanted - len(full)


def test_suggestions_try_the_configured_values_first_and_count_true():
    config = ProtocolConfig(cell_size=2.0, cells=6)
    suggestion = suggest(narrow_room(), Camera(), config)
    first = suggestion.fits[0]
    assert (first.cell_size, first.viewpoint_distance) == (2.0, 1.0) and not first.enough
    for fit in suggestion.fits:
        protocol = Protocol(narrow_room(), Camera(), config.model_copy(update={"cell_size": fit.cell_size, "viewpoint_distance": fit.viewpoint_distance}))
        assert fit.cells == len(protocol.eligible_cells(protocol.free_cells(), 1.5)) and fit.complete
    assert suggestion.best is not None and suggestion.best.cell_size < 2.0
    with pytest.raises(InputError, match=r"only \d of its \d+ cells of 2.0 m .* 6 wanted; protocol.cell_size = 1.5 gives at least 6, or lower protocol.cells to 3"):
        Protocol(narrow_room(), Camera(), config).plan("narrow")
