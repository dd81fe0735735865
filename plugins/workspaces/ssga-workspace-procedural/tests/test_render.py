"""Rendering through the mesh renderer: what a camera in a procedural home sees."""

from __future__ import annotations

import numpy as np
import pytest

from ssga_core import Camera, Pose
from ssga_workspace_procedural import CATEGORIES, Home
from ssga_workspace_procedural.workspace import ProceduralWorkspace

CAMERA = Camera(128, 128, 90.0)


@pytest.fixture(scope="module")
def workspace(home: Home) -> ProceduralWorkspace:
    return ProceduralWorkspace(home, CAMERA)


def test_views_from_free_poses_see_a_closed_room(workspace: ProceduralWorkspace, home: Home) -> None:
    x0, y0, x1, y1 = home.floor_plan.bounds
    diagonal = float(np.hypot(x1 - x0, y1 - y0))
    seen: set[int] = set()
    for pose in home.sample_poses(8, np.random.default_rng(0)):
        view = workspace.render(pose)
        assert view.camera == CAMERA and view.pose == pose
        # the house is closed: every ray hits something within the house
        assert view.valid_depth().all()
        assert np.isfinite(view.depth).all() and view.depth.max() < diagonal
        assert (view.semantic >= 1).all() and (view.instance >= 1).all()
        assert view.rgb.std() > 5  # textured and shaded, not a flat fill
        seen |= set(np.unique(view.semantic).tolist())
    assert {CATEGORIES[c] for c in ("wall", "floor", "ceiling")} <= seen
    assert len(seen) >= 6


def test_a_camera_facing_an_object_sees_it_in_the_middle(workspace: ProceduralWorkspace, home: Home) -> None:
    looked_at = 0
    for obj in home.furniture:
        if obj.height < 0.7:  # low things (rugs, nightstands) can sit below the middle of the image
            continue
        pose = home.view_of(obj.name)
        if pose is None:
            continue
        view = workspace.render(pose)
        h, w = CAMERA.shape
        centre = view.instance[h // 4 : 3 * h // 4, 3 * w // 8 : 5 * w // 8]
        assert obj.instance_id in centre, f"{obj.name} not in the middle of the view from {pose}"
        looked_at += 1
    assert looked_at >= 5


def test_depth_is_planar_distance_to_a_wall() -> None:
    from ssga_workspace_procedural import HomeConfig, generate_home

    home = generate_home(HomeConfig(seed=0, rooms=1, width=6.0, depth=5.0, furniture_density=0.0))
    view = ProceduralWorkspace(home, CAMERA).render(Pose(2.0, 2.5, 0.0, 1.5))  # looking at the x = 6 - 0.06 wall
    wall = 6.0 - home.config.wall_thickness / 2
    np.testing.assert_allclose(view.depth[52:76, 40:88], wall - 2.0, atol=1e-4)
    assert (view.semantic[52:76, 40:88] == CATEGORIES["wall"]).all()


def test_the_renderer_is_built_once_on_first_use(home: Home) -> None:
    ws = ProceduralWorkspace(home, CAMERA)
    assert "renderer" not in vars(ws)
    ws.render(home.sample_poses(1, np.random.default_rng(1))[0])
    renderer = ws.renderer
    ws.render(home.sample_poses(1, np.random.default_rng(2))[0])
    assert ws.renderer is renderer
