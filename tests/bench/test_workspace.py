"""The floor-plan file format, read and written by the core for every workspace source."""

from __future__ import annotations

import pytest
import shapely

from ssga_core import InputError
from ssga_bench.io import read_json, write_json
from ssga_bench.workspace import FloorPlan


def test_floor_plans_round_trip_with_holes(tmp_path):
    room = shapely.box(0, 0, 6, 4).difference(shapely.box(2, 1, 3, 2))  # a table's footprint cut out
    walls = shapely.box(-0.1, -0.1, 6.1, 4.1).difference(shapely.box(0, 0, 6, 4))
    write_json(tmp_path / "plan.json", FloorPlan(free=room, occluders=walls).to_json())
    plan = FloorPlan.from_json(read_json(tmp_path / "plan.json"), "plan.json")
    assert plan.free.area == pytest.approx(23.0)
    assert plan.occluders.area == pytest.approx(walls.area)
    assert not plan.can_stand(2.5, 1.5) and plan.can_stand(1.0, 1.0)


def test_outlines_alone_and_occluders_cut_from_the_free_floor():
    data = {"free": [[[0, 0], [4, 0], [4, 4], [0, 4]]], "occluders": [[[1, 1], [2, 1], [2, 2], [1, 2]]]}
    assert FloorPlan.from_json(data).free.area == pytest.approx(15.0)
    assert FloorPlan.from_json({"free": data["free"]}).occluders.is_empty


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "no such file"),
        ("[1, 2", "not valid JSON"),
        ('{"occluders": []}', 'expected {"free"'),
        ('{"free": 3}', "'free' must be a list of polygons"),
        ('{"free": [[[0, 0], [1, 0]]]}', r"free\[0\] must be a ring of at least 3"),
        ('{"free": [[[0, 0], [1, 1], [1, 0], [0, 1]]]}', r"free\[0\] is not a simple polygon"),
        ('{"free": [[[0, 0], [1, 0], [1, 1]]], "occluders": [[[-1, -1], [2, -1], [2, 2], [-1, 2]]]}', "no floor to stand on"),
    ],
)
def test_bad_floor_plans_are_one_line_errors_naming_the_file(tmp_path, content, expected):
    path = tmp_path / "plan.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(InputError, match=expected) as error:
        FloorPlan.from_json(read_json(path), str(path))
    assert "plan.json" in str(error.value) and "\n" not in str(error.value)
