"""Render speed on an HM3D-sized mesh, per core (``make bench``).

HM3D's scenes as Habitat ships them are half a million to a million textured triangles,
with a second mesh of the same surfaces for the semantic annotations. None can ship here,
so a procedural home stands in: 8 rooms in 18 x 14 m, exported to GLB as the procedural
workspace writes it, loaded back through the mesh workspace, every triangle split in four
until there are at least 500,000 (728,192; 42 textures in one atlas page). Views are
256 x 256, hfov 90, from poses in the home's free space, rendered in one process on one
thread (OpenCV's pool off), timed in CPU time (``time.process_time``), so views/s is per
core and holds on a machine other jobs load: compare it with the 50 views/s per core
roof. ``with_labels`` adds the same surfaces again as label surfaces, as HM3D's semantic
mesh is, which costs a second ray cast per view.
Run alone with ``pytest benchmarks/bench_render_hm3d.py -o python_files='bench_*.py' --benchmark-enable``.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
import trimesh

pytest.importorskip("ssga_workspace_mesh")
pytest.importorskip("ssga_workspace_procedural")

from ssga_core import Camera, Pose  # noqa: E402
from ssga_workspace_mesh.loading import load_mesh_scene  # noqa: E402
from ssga_workspace_mesh.meshdata import FACE_INSTANCE, FACE_SEMANTIC, LABEL_SURFACE  # noqa: E402
from ssga_workspace_mesh.renderer import MeshRenderer  # noqa: E402
from ssga_workspace_mesh.scenes import subdivided  # noqa: E402
from ssga_workspace_procedural.export import export_glb  # noqa: E402
from ssga_workspace_procedural.generator import HomeConfig, generate_home  # noqa: E402

MIN_TRIANGLES = 500_000
ROOF_VIEWS_PER_S = 50.0
POSES = 60


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    return generate_home(HomeConfig(seed=0, rooms=8, width=18.0, depth=14.0))


@pytest.fixture(scope="module")
def hm3d_sized(home, tmp_path_factory) -> tuple[trimesh.Scene, dict[str, tuple[int, int]]]:
    path = tmp_path_factory.mktemp("hm3d-sized") / "home.glb"
    export_glb(home, path)
    scene, ids = load_mesh_scene(path)
    return subdivided(scene, MIN_TRIANGLES), ids


@pytest.fixture(scope="module")
def poses(home) -> list[Pose]:
    return home.sample_poses(POSES, np.random.default_rng(0))


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(threads)


def _with_labels(scene: trimesh.Scene) -> trimesh.Scene:
    """``scene`` plus a copy of its surfaces as label surfaces, each face its own id (as dense as HM3D's)."""
    out = scene.copy()
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        mesh = scene.geometry[name]
        ids = np.arange(len(mesh.faces), dtype=np.int32)
        label = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False, metadata={LABEL_SURFACE: True, FACE_SEMANTIC: ids % 40, FACE_INSTANCE: ids})
        out.add_geometry(label, geom_name=f"labels:{name}", transform=transform)
    return out


@pytest.mark.benchmark(timer=time.process_time)
@pytest.mark.parametrize("labels", ["rgb_depth_ids", "with_labels"])
def test_render_hm3d_sized_view(benchmark, hm3d_sized, poses, labels):
    scene, ids = hm3d_sized
    renderer = MeshRenderer(_with_labels(scene) if labels == "with_labels" else scene, Camera(width=256, height=256, hfov_deg=90.0), ids=ids)
    assert renderer.num_triangles >= MIN_TRIANGLES
    benchmark.extra_info["triangles"] = renderer.num_triangles
    it = iter(poses * 1000)
    view = benchmark(lambda: renderer.render(next(it)))
    assert view.valid_depth().mean() > 0.99, "inside the home every ray hits something"
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        per_core = 1.0 / stats.stats.median
        benchmark.extra_info["views_per_s_per_core"] = round(per_core, 1)
        benchmark.extra_info["share_of_roof"] = round(per_core / ROOF_VIEWS_PER_S, 2)
