"""The renderer against geometry whose images are known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from ssga_core import Camera, Pose
from ssga_workspace_mesh import renderer as renderer_module
from ssga_workspace_mesh.renderer import MeshRenderer
from ssga_workspace_mesh.scenes import CRATE, CRATES, WALL, box_room, subdivided, textured_quad


def test_depth_reprojects_onto_the_mesh(room, camera):
    renderer = MeshRenderer(room, camera)
    surface = trimesh.util.concatenate(list(room.dump()))
    rng = np.random.default_rng(0)
    for pose in (Pose(0.5, -0.3, 0.4, 1.5), Pose(-1.0, 1.0, 2.5, 1.2), Pose(3.0, 0.0, -2.0, 1.7)):
        view = renderer.render(pose)
        assert view.valid_depth().all(), "a closed room leaves no pixel without a hit"
        v, u = rng.integers(0, 256, (2, 400))
        points = pose.to_world(camera.unproject(view.depth[v, u], np.stack([u, v], axis=-1).astype(np.float32)))
        _, distance, _ = trimesh.proximity.closest_point(surface, points)
        assert distance.max() < 1e-3


def test_depth_is_planar_z_not_ray_length(camera):
    # Facing the east wall (inner face at x = 4) from 1 m: planar depth is 1 m at every pixel,
    # although the ray to an image corner is sqrt(3) m long.
    view = MeshRenderer(box_room(crates=False), camera).render(Pose(3.0, 0.0, 0.0, 1.5))
    np.testing.assert_allclose(view.depth, 1.0, atol=1e-5)
    assert (view.semantic == WALL).all()


def test_a_known_pose_sees_known_objects(room, camera):
    renderer = MeshRenderer(room, camera)
    pose = Pose(0.0, 0.0, 0.0, 1.5)  # looking along +x: +y is on the camera's left
    view = renderer.render(pose)
    (x, y), (_, _, dz) = CRATES["crate_a"]  # at (2, 1.5): ahead and to the left
    front = np.array([[x - 0.3, y, 1.0]])  # a point on the crate face that looks at the camera
    uv, depth = camera.project(pose.to_camera(front))
    u, v = np.rint(uv[0]).astype(int)
    assert u < camera.width / 2, "an object on the camera's left is in the left half"
    assert view.semantic[v, u] == CRATE
    assert view.instance[v, u] == room.geometry["crate_a"].metadata["instance_id"]
    assert view.depth[v, u] == pytest.approx(depth[0], abs=1e-4)
    # The east wall straight ahead, at the principal point's row and column.
    assert view.semantic[128, 128] == WALL
    assert view.instance[128, 128] == room.geometry["wall_east"].metadata["instance_id"]
    assert view.depth[128, 128] == pytest.approx(4.0, abs=1e-3)
    # Turning left by 90 degrees puts the north wall (green) ahead.
    ahead = renderer.render(Pose(0.0, 0.0, math.pi / 2, 1.5)).instance[128, 128]
    assert ahead == room.geometry["wall_north"].metadata["instance_id"]


def test_misses_are_unknown(camera):
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    box.apply_translation((5.0, 0.0, 1.5))
    view = MeshRenderer(box, camera).render(Pose(0.0, 0.0, 0.0, 1.5))
    hit = view.depth > 0
    assert 0 < hit.mean() < 0.1
    assert (view.semantic[~hit] == -1).all() and (view.instance[~hit] == -1).all()
    assert (view.rgb[~hit] == 0).all()
    assert (view.instance[hit] == 0).all(), "without ids, the instance is the geometry's index"


def _facing_quad(image: np.ndarray, distance: float = 2.0, height: float = 1.5) -> trimesh.Trimesh:
    """A quad filling exactly the 90-degree view of a camera at the origin looking along +x."""
    d = distance
    # Seen from the camera: top-left is +y (left) and up.
    corners = [[d, d, height + d], [d, -d, height + d], [d, -d, height - d], [d, d, height - d]]
    return textured_quad(np.array(corners), image)


def test_texture_is_reproduced_upright_and_unmirrored(camera, pattern):
    view = MeshRenderer(_facing_quad(pattern), camera, shading=False).render(Pose(0.0, 0.0, 0.0, 1.5))
    # Each pixel centre lands on a texel centre, so bilinear sampling returns the texel itself.
    assert np.abs(view.rgb.astype(int) - pattern).max() <= 1


def test_texture_under_a_yaw_and_an_offset(camera, pattern):
    # The same quad turned with the camera: rotate everything by 2 rad about z and move it.
    pose = Pose(1.0, -2.0, 2.0, 1.5)
    quad = _facing_quad(pattern)
    quad.vertices = pose.to_world(Pose(0.0, 0.0, 0.0, 1.5).to_camera(quad.vertices))
    view = MeshRenderer(quad, camera, shading=False).render(pose)
    assert np.abs(view.rgb.astype(int) - pattern).max() <= 1


def test_shading_tells_walls_apart(camera):
    grey = box_room(crates=False)
    for mesh in grey.geometry.values():
        mesh.visual.face_colors = (200, 200, 200, 255)
    renderer = MeshRenderer(grey, camera)
    centre = [renderer.render(Pose(0.0, 0.0, yaw, 1.5)).rgb[128, 128] for yaw in (0, math.pi / 2, math.pi, -math.pi / 2)]
    assert len({tuple(c) for c in centre}) == 4
    flat = MeshRenderer(grey, camera, shading=False).render(Pose(0.0, 0.0, 0.0, 1.5))
    assert (flat.rgb == 200).all()


def test_vertex_colours_are_interpolated(camera):
    quad = _facing_quad(np.zeros((2, 2, 3), np.uint8))
    rgba = [[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [0, 0, 0, 255]]  # corners TL, TR, BR, BL
    quad.visual = trimesh.visual.ColorVisuals(quad, vertex_colors=rgba)
    view = MeshRenderer(quad, camera, shading=False).render(Pose(0.0, 0.0, 0.0, 1.5))
    np.testing.assert_allclose(view.rgb[0, 0], [255, 0, 0], atol=3)  # top-left corner is red
    np.testing.assert_allclose(view.rgb[0, -1], [0, 255, 0], atol=3)  # top-right corner is green


def test_ids_argument_overrides_metadata(room, camera):
    view = MeshRenderer(room, camera, ids={"wall_east": (42, 99)}).render(Pose(0.0, 0.0, 0.0, 1.5))
    assert (view.semantic[128, 128], view.instance[128, 128]) == (42, 99)


def test_node_transforms_and_instancing_are_applied(camera):
    scene = trimesh.Scene()
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    for node, y in (("left", 1.5), ("right", -1.5)):
        shift = trimesh.transformations.translation_matrix((4.0, y, 1.5))
        scene.add_geometry(box, geom_name="box", node_name=node, transform=shift)
    view = MeshRenderer(scene, camera).render(Pose(0.0, 0.0, 0.0, 1.5))
    row = view.depth[128]
    assert row[:100].max() > 0 and row[156:].max() > 0 and row[118:138].max() == 0


def test_render_many_in_worker_processes_matches_render(room, camera, monkeypatch):
    monkeypatch.setattr(renderer_module, "MIN_POSES_PER_WORKER", 1)  # start processes even for a short batch
    renderer = MeshRenderer(room, camera)
    poses = [Pose(0.3 * i - 1.0, 0.1 * i, 0.7 * i, 1.5) for i in range(4)]
    views = renderer.render_many(poses, workers=2)
    for pose, view in zip(poses, views, strict=True):
        alone = renderer.render(pose)
        assert view.pose == pose
        np.testing.assert_array_equal(view.rgb, alone.rgb)
        np.testing.assert_array_equal(view.depth, alone.depth)
        np.testing.assert_array_equal(view.instance, alone.instance)


def test_views_follow_the_camera(room):
    camera = Camera(width=160, height=120, hfov_deg=70.0)
    view = MeshRenderer(room, camera).render(Pose(0.0, 0.0, 0.0, 1.5))
    assert view.rgb.shape == (120, 160, 3) and view.camera == camera


def test_a_subdivided_scene_renders_as_before(room, camera, pattern):
    scene = room.copy()
    scene.add_geometry(_facing_quad(pattern, distance=3.9), geom_name="painting")  # on the east wall
    vertex_coloured = _facing_quad(np.zeros((2, 2, 3), np.uint8), distance=3.8)
    vertex_coloured.visual = trimesh.visual.ColorVisuals(vertex_coloured, vertex_colors=[[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [0, 0, 0, 255]])
    behind = trimesh.transformations.rotation_matrix(math.pi, (0, 0, 1))  # fills the view of a camera turned round
    scene.add_geometry(vertex_coloured, geom_name="gradient", transform=behind)
    dense = subdivided(scene, 20_000)
    assert sum(len(g.faces) for g in dense.geometry.values()) >= 20_000
    before, after = MeshRenderer(scene, camera), MeshRenderer(dense, camera)
    for pose in (Pose(0.0, 0.0, 0.0, 1.5), Pose(0.0, 0.0, math.pi, 1.5), Pose(1.0, -1.0, 0.8, 1.4)):
        a, b = before.render(pose), after.render(pose)
        np.testing.assert_allclose(a.depth, b.depth, atol=1e-4)
        assert (a.instance == b.instance).mean() > 0.999
        assert (np.abs(a.rgb.astype(int) - b.rgb.astype(int)).max(axis=-1) <= 2).mean() > 0.999
