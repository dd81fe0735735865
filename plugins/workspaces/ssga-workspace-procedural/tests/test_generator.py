"""Generation: determinism, a connected free space, furniture clear of walls, doors and each other."""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Callable

import numpy as np
import pytest
import shapely

from ssga_core import InputError
from ssga_workspace_procedural import CATEGORIES, Home, HomeConfig, generate_home


def _fingerprint(home: Home) -> list[tuple]:
    out = []
    for o in home.objects:
        visual = o.mesh.visual
        image = visual.material.image.tobytes() if hasattr(visual, "material") else visual.face_colors.tobytes()
        out.append((o.name, o.semantic_id, o.instance_id, o.mesh.vertices.tobytes(), o.mesh.faces.tobytes(), image))
    return out


def test_the_same_seed_gives_identical_homes() -> None:
    a, b = generate_home(HomeConfig(seed=11)), generate_home(HomeConfig(seed=11))
    assert _fingerprint(a) == _fingerprint(b)
    assert shapely.to_wkb(a.floor_plan.free) == shapely.to_wkb(b.floor_plan.free)
    assert shapely.to_wkb(a.floor_plan.occluders) == shapely.to_wkb(b.floor_plan.occluders)


def test_distinct_seeds_give_distinct_homes(home_for: Callable[..., Home]) -> None:
    plans = [shapely.to_wkb(home_for(s).floor_plan.free) for s in range(4)]
    layouts = [home_for(s).layout.cells for s in range(4)]
    assert len(set(plans)) == 4
    assert len(set(layouts)) == 4


def test_the_free_space_is_one_polygon_inside_the_house_and_off_the_occluders(varied_home: Home) -> None:
    home = varied_home
    free, occluders = home.floor_plan.free, home.floor_plan.occluders
    assert free.geom_type == "Polygon" and free.is_valid
    outer = home.layout.outer
    assert outer.polygon().contains(free)
    assert free.intersection(occluders).area < 1e-9
    # a camera keeps robot_radius from every wall
    assert free.distance(shapely.union_all(home.wall_parts)) >= home.config.robot_radius - 1e-6


def test_every_room_is_reachable_through_doorways(varied_home: Home) -> None:
    home = varied_home
    free = home.floor_plan.free
    assert len(home.rooms) == home.config.rooms
    for room in home.rooms:
        assert room.interior.polygon().intersection(free).area > 1.0, f"room {room.index} has no free floor"
    for door in home.layout.doors:  # the free polygon runs through every doorway
        assert free.intersects(door.opening(home.config.wall_thickness).centroid)
    seen, todo = {0}, deque([0])
    while todo:
        r = todo.popleft()
        for d in home.layout.doors_of(r):
            other = d.rooms[1] if d.rooms[0] == r else d.rooms[0]
            if other not in seen:
                seen.add(other)
                todo.append(other)
    assert seen == set(range(len(home.rooms)))


def test_furniture_stands_on_the_floor_clear_of_walls_doorways_and_each_other(varied_home: Home) -> None:
    home = varied_home
    walls = shapely.union_all(home.wall_parts)
    doors = shapely.union_all([d.opening(home.config.wall_thickness) for d in home.layout.doors])
    solid = [o for o in home.furniture if not o.flat]
    assert len(solid) >= 2 * len(home.rooms) - 2
    for o in home.furniture:
        assert not o.footprint.intersects(walls), o.name
        assert not o.footprint.intersects(doors), o.name
        assert home.rooms[o.room].interior.polygon().contains(o.footprint), o.name
        lo, hi = o.mesh.bounds
        assert abs(lo[2]) < 1e-6, f"{o.name} floats or sinks: bottom at {lo[2]}"
        assert hi[2] < home.config.wall_height
        # the footprint holds the mesh
        assert shapely.box(lo[0], lo[1], hi[0], hi[1]).difference(o.footprint.buffer(1e-6)).area < 1e-9, o.name
    for i, a in enumerate(solid):
        for b in solid[i + 1 :]:
            assert not a.footprint.intersects(b.footprint), f"{a.name} overlaps {b.name}"


def test_tall_furniture_and_walls_are_the_occluders(varied_home: Home) -> None:
    home = varied_home
    occluders = home.floor_plan.occluders
    for o in home.furniture:
        inside = occluders.covers(o.footprint)
        assert inside == (o.height >= home.config.occluder_height), o.name


def test_objects_are_named_and_labelled_consistently(home: Home) -> None:
    iids = [o.instance_id for o in home.objects]
    assert len(set(iids)) == len(iids) and min(iids) == 1
    for o in home.objects:
        assert o.name == f"{o.category}-{o.instance_id:04d}"
        assert o.semantic_id == CATEGORIES[o.category]
        meta = home.scene.geometry[o.name].metadata
        assert (meta["category"], meta["semantic_id"], meta["instance_id"]) == (o.category, o.semantic_id, o.instance_id)
    assert set(home.ids()) == set(home.scene.geometry)
    present = {o.category for o in home.objects}
    assert {"wall", "floor", "ceiling", "painting"} <= present
    assert len(present) >= 8


def test_every_room_has_its_own_textures(home: Home) -> None:
    walls = [r.wall.image.tobytes() for r in home.rooms]
    floors = [r.floor.image.tobytes() for r in home.rooms]
    assert len(set(walls)) == len(walls) and len(set(floors)) == len(floors)


def test_triangle_budget(varied_home: Home) -> None:
    assert 1_000 < varied_home.triangle_count < 50_000


def test_density_scales_the_furniture(home_for: Callable[..., Home]) -> None:
    empty = generate_home(HomeConfig(seed=4, furniture_density=0.0))
    full = generate_home(HomeConfig(seed=4, furniture_density=2.0))
    assert not empty.furniture and not empty.of_category("painting")
    assert len(full.furniture) > len(home_for(4).furniture) * 0.9
    assert empty.floor_plan.free.area > full.floor_plan.free.area


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"rooms": 0}, "at least one room"),
        ({"rooms": 8, "width": 6.0, "depth": 5.0}, "cannot hold 8 rooms"),
        ({"door_width": 0.4}, "wider than the robot"),
    ],
)
def test_impossible_configs_are_input_errors(kwargs: dict, message: str) -> None:
    with pytest.raises(InputError, match=re.escape(message)):
        generate_home(HomeConfig(**kwargs))


def test_view_of_looks_at_the_object(home: Home) -> None:
    obj = next(o for o in home.furniture if not o.flat)
    pose = home.view_of(obj.name)
    assert pose is not None and home.floor_plan.can_stand(pose.x, pose.y)
    c = obj.footprint.centroid
    to_obj = np.array([c.x - pose.x, c.y - pose.y])
    assert np.dot(to_obj / np.linalg.norm(to_obj), pose.forward[:2]) > 0.999
