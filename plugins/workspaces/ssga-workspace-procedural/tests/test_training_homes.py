"""Homes for learned plugins' training: the same views every time, standing on free floor."""

from __future__ import annotations

import numpy as np

from ssga_workspace_procedural.training_homes import BENCH_HOME, DEMO_HOME, bench_and_demo_sized, open_home, standing_views


def test_standing_views_are_drawn_from_the_seed_and_stand_on_free_floor():
    settings = {**DEMO_HOME, "rooms": 2, "home_width": 8.0, "home_depth": 6.0}
    first = list(standing_views(7, 3, settings))
    again = list(standing_views(7, 3, settings))
    other = list(standing_views(8, 3, settings))
    plan = open_home(7, settings).floor_plan
    assert len(first) == 3 and all(plan.can_stand(v.pose.x, v.pose.y) for v in first)
    assert all(np.array_equal(a.rgb, b.rgb) and a.pose == b.pose for a, b in zip(first, again, strict=True))
    assert not np.array_equal(first[0].rgb, other[0].rgb)
    assert first[0].depth is not None and first[0].semantic is not None


def test_even_seeds_are_bench_sized_and_odd_ones_demo_sized():
    assert bench_and_demo_sized(2000) == BENCH_HOME and bench_and_demo_sized(2001) == DEMO_HOME
    assert open_home(3, {**BENCH_HOME, "rooms": 3}).floor_plan.bounds[2] > 12.0  # an 18 m wide house
