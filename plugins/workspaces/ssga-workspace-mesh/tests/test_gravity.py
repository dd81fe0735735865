"""Levelling scans in any orientation: up found from the mesh (or given), floor put at z = 0."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from ssga_core import InputError
from ssga_workspace_mesh.gravity import parse_up_axis, rotation_to_z
from ssga_workspace_mesh.loading import load_mesh_scene, save_mesh_scene
from ssga_workspace_mesh.plugin import MeshConfig, MeshWorkspaceSource
from ssga_workspace_mesh.scenes import box_room, furnished_room


def scan_of(scene: trimesh.Scene, seed: int, noise: float = 0.005) -> trimesh.Scene:
    """``scene`` as a scanner would give it: finer triangles whose vertices are off by ``noise`` metres."""
    rng = np.random.default_rng(seed)
    scan = trimesh.Scene()
    for name, geom in scene.geometry.items():
        fine = geom.subdivide().subdivide()
        fine.vertices = fine.vertices + rng.normal(0.0, noise, fine.vertices.shape)
        scan.add_geometry(fine, geom_name=name)
    return scan


def floor_top(scene: trimesh.Scene) -> np.ndarray:
    """World positions of the vertices of the upward faces of the geometry named ``floor``
    (its walkable top; up within 30 degrees of ``+z``, so a levelling off by more finds none)."""
    node = next(n for n in scene.graph.nodes_geometry if scene.graph[n][1] == "floor")
    transform, name = scene.graph[node]
    floor = scene.geometry[name].copy()
    floor.apply_transform(transform)
    up = floor.face_normals[:, 2] > math.cos(math.radians(30.0))
    return floor.vertices[np.unique(floor.faces[up])]


def plane_normal(points: np.ndarray) -> np.ndarray:
    """Unit normal of the plane best through ``points`` (smallest principal axis), pointing up."""
    _, _, vt = np.linalg.svd(points - points.mean(axis=0))
    return vt[-1] if vt[-1][2] >= 0 else -vt[-1]


def save_turned(scene: trimesh.Scene, path, rotation: np.ndarray, shift=(0.0, 0.0, 0.0)):
    """Write ``scene`` turned by ``rotation`` and moved, as a file with no up convention (as a scanner's)."""
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = rotation, shift
    turned = scene.copy()
    turned.apply_transform(transform)
    save_mesh_scene(turned, path, up_axis="z")
    return path


@pytest.mark.parametrize(("seed", "ceiling"), [(0, True), (1, True), (2, False), (3, False)])
def test_a_scan_turned_any_way_comes_back_level_with_its_floor_at_zero(tmp_path, seed, ceiling):
    rng = np.random.default_rng(seed)
    room = scan_of(furnished_room((3.5, 4.4), seed=seed, pieces=5), seed)
    if not ceiling:  # scanned from below, as a handheld scan often is
        room.delete_geometry("ceiling")
    rotation = trimesh.transformations.random_rotation_matrix(rand=rng.random(3))[:3, :3]
    path = save_turned(room, tmp_path / "scan.glb", rotation, shift=rng.uniform(-5, 5, 3))
    scene, _ = load_mesh_scene(path, up_axis="auto")
    top = floor_top(scene)
    assert math.degrees(math.acos(plane_normal(top)[2])) < 1.0, "the floor is level"
    assert abs(np.median(top[:, 2])) < 0.01, "the floor is at z = 0"
    levelling = scene.metadata["levelling"]
    true_up = rotation @ np.array([0.0, 0.0, 1.0])
    assert math.degrees(math.acos(np.clip(levelling.up @ true_up, -1.0, 1.0))) < 1.0
    assert levelling.found and "found up" in levelling.describe()


def test_auto_on_a_y_up_file_matches_up_axis_y(tmp_path):
    save_mesh_scene(box_room(), tmp_path / "room.glb", up_axis="y")
    by_name, _ = load_mesh_scene(tmp_path / "room.glb", up_axis="y")
    found, _ = load_mesh_scene(tmp_path / "room.glb", up_axis="auto")
    np.testing.assert_allclose(found.bounds, by_name.bounds, atol=1e-4)
    axis, tilt = found.metadata["levelling"].nearest_axis()
    assert axis == "+y" and tilt < 0.1


def test_a_given_up_vector_levels_the_mesh_and_says_so(tmp_path, capsys):
    # The office: its floor's normal is (-0.01, -0.80, -0.60) in the scan's frame.
    up = np.array([-0.01, -0.80, -0.60])
    up /= np.linalg.norm(up)
    path = save_turned(furnished_room((3.5, 4.4), seed=1), tmp_path / "office.glb", rotation_to_z(up).T, shift=(0.3, 1.2, -0.7))
    top = floor_top(load_mesh_scene(path, up_axis=(-0.01, -0.80, -0.60))[0])
    assert math.degrees(math.acos(plane_normal(top)[2])) < 0.01 and abs(np.median(top[:, 2])) < 1e-3
    workspace = MeshWorkspaceSource(MeshConfig(path=path, up_axis=[-0.01, -0.80, -0.60])).open()
    assert workspace.levelling is not None and not workspace.levelling.found
    said = capsys.readouterr().err
    assert "up given as (-0.010, -0.800, -0.600)" in said and "36.9 deg from its -y axis" in said
    assert workspace.floor_plan.free.area > 0.5 * 3.5 * 4.4, "the floor plan is found on the levelled floor"


@pytest.mark.parametrize("bad", ["x", [0, 0, 0], [1, 2], "sideways", [1.0, float("nan"), 0.0]])
def test_bad_up_axes_are_one_line_errors(bad):
    with pytest.raises(InputError, match=r"scan.glb: up_axis must be 'y', 'z', 'auto' or a non-zero \[x, y, z\] vector"):
        parse_up_axis(bad, "scan.glb")


def test_rotation_to_z_is_the_smallest_turn():
    for up in ([0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [0.3, -0.2, 0.9]):
        u = np.asarray(up) / np.linalg.norm(up)
        turn = rotation_to_z(u)
        np.testing.assert_allclose(turn @ u, [0.0, 0.0, 1.0], atol=1e-12)
        np.testing.assert_allclose(turn @ turn.T, np.eye(3), atol=1e-12)
        if abs(u[2]) < 1.0:  # the axis of the turn is horizontal: nothing turns about the vertical
            axis = np.cross(u, [0.0, 0.0, 1.0])
            np.testing.assert_allclose(turn @ axis, axis, atol=1e-12)


def test_a_levelled_scene_written_again_opens_without_levelling_anew(tmp_path, capsys):
    scene, _ = load_mesh_scene(save_turned(box_room(), tmp_path / "scan.glb", rotation_to_z(np.array([0.0, 0.6, 0.8])).T), up_axis="auto")
    save_mesh_scene(scene, tmp_path / "level.glb", up_axis="z")  # the levelling's record goes into the file's extras
    capsys.readouterr()
    workspace = MeshWorkspaceSource(MeshConfig(path=tmp_path / "level.glb", up_axis="z")).open()
    assert workspace.levelling is None and capsys.readouterr().err == ""
    assert workspace.floor_plan.can_stand(0.0, 0.0)
