"""Floor plans derived from meshes and read from JSON."""

from __future__ import annotations

import json

import pytest
import shapely
import trimesh

from ssga_core import InputError
from ssga_workspace_mesh.floorplan import floor_plan_from_mesh, load_floor_plan
from ssga_workspace_mesh.scenes import CRATES, box_room, solid_box


def test_box_room_plan_is_free_inside_and_blocked_along_walls(room):
    plan = floor_plan_from_mesh(room, camera_height=1.5, clearance=0.25)
    assert plan.can_stand(0.0, 0.0) and plan.can_stand(3.6, 2.6)
    assert not plan.can_stand(3.9, 0.0), "within the clearance of the east wall"
    assert not plan.can_stand(5.0, 0.0), "outside the room"
    for (x, y), _ in CRATES.values():
        assert not plan.can_stand(x, y)
        assert plan.occluders.covers(shapely.Point(x, y)), "solids are filled, not just outlined"
    # The walls (inner faces at x = +-4, y = +-3, 0.1 m thick) are occluders all round, the room's inside is not.
    for x, y in ((4.05, 0.0), (-4.05, 1.0), (0.0, 3.05), (1.0, -3.05)):
        assert plan.occluders.covers(shapely.Point(x, y))
    assert not plan.occluders.covers(shapely.Point(0.0, 0.0))
    inside = (8 - 2 * 0.25) * (6 - 2 * 0.25)
    assert 0.85 * inside < plan.free.area < inside


def test_open_room_on_open_ground_is_free_only_inside():
    scene = box_room(crates=False)
    scene.delete_geometry("ceiling")
    scene.add_geometry(solid_box((30.0, 30.0, 0.1), (0.0, 0.0, -0.06), (90, 160, 90, 255)), geom_name="lawn")
    plan = floor_plan_from_mesh(scene)
    assert plan.can_stand(0.0, 0.0)
    assert not plan.can_stand(8.0, 8.0), "open ground outside the walls is not in the building"
    assert plan.free.bounds[2] < 4.0


def test_zero_thickness_walls_are_outlined():
    shell = trimesh.creation.box((8.0, 6.0, 3.0))
    shell.apply_translation((0.0, 0.0, 1.5))
    shell.invert()  # single surfaces facing into the room
    plan = floor_plan_from_mesh(shell)
    assert plan.can_stand(0.0, 0.0)
    assert plan.occluders.covers(shapely.Point(4.0, 0.0)) and not plan.occluders.covers(shapely.Point(0.0, 0.0))


def test_a_mesh_without_floor_at_zero_is_an_input_error(room):
    raised = room.copy()
    raised.apply_translation((0.0, 0.0, 5.0))
    with pytest.raises(InputError, match="found no free floor"):
        floor_plan_from_mesh(raised)


def test_json_floor_plan(tmp_path):
    path = tmp_path / "plan.json"
    path.write_text(json.dumps({"free": [[[0, 0], [4, 0], [4, 3], [0, 3]]], "occluders": [[[1, 1], [2, 1], [2, 2], [1, 2]]]}))
    plan = load_floor_plan(path)
    assert plan.can_stand(0.5, 0.5) and not plan.can_stand(1.5, 1.5), "occluders are cut out of the free floor"
    assert plan.occluders.area == pytest.approx(1.0)
    assert plan.free.area == pytest.approx(11.0)


