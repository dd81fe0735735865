"""Measure a ScanNet-sized PLY scan through the mesh workspace: load time, peak memory, render time.

No scan can ship here, so a stand-in is generated: a furnished room (``scenes.furnished_room``,
6 x 5 m, 8 pieces) as ScanNet's ``*_vh_clean.ply`` are, without its ceiling and with walls
that end at 1.4 m, merged into one mesh with shared vertices, split into triangles of about
the same size until it has ``--faces`` of them (1.5 million, ScanNet's size, by default),
every vertex given its own colour (a pattern over position, so colours vary inside faces),
and written as binary little-endian PLY with ScanNet's properties (``float x y z``,
``uchar red green blue alpha``, ``list uchar int vertex_indices``); ``--ascii`` writes it
as text too.

Each phase runs in a fresh process, started from a parent that holds nothing (Linux carries
the parent's peak into a child's ``ru_maxrss`` across fork and exec), so that its peak
resident memory (``ru_maxrss``, and ``VmHWM`` as a check) is its own; ``imports`` is the
interpreter with the plugin's modules imported, the floor under the others:

* ``read``: ``load_mesh_scene(path, up_axis="z")``, the file to a trimesh scene;
* ``auto``: the same with ``up_axis="auto"`` (finding up and the floor, then turning the mesh);
* ``open``: ``MeshWorkspaceSource(...).open()``, what ``ssga`` does before it renders: the
  load, the floor plan (here twice: the scan ends below 1.5 m, so the plan is derived again
  lower), the renderer (flattening, Embree's BVH);
* ``render``: after ``open``, 256 x 256 views (hfov 90) from 20 poses in the free floor, one
  thread; median wall and CPU time per view.

Run from the repository root::

    .venv/bin/python plugins/workspaces/ssga-workspace-mesh/scripts/measure_ply.py [--faces 1500000] [--ascii]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PHASES = ("imports", "read", "auto", "open", "render")
MAKE_PHASES = ("make", "ascii")


def make_scan(path: Path, faces: int) -> dict[str, int]:
    """Write the stand-in scan to ``path`` (binary PLY) and return its size."""
    import numpy as np
    import trimesh

    from ssga_workspace_mesh.scenes import furnished_room

    room = furnished_room((6.0, 5.0), seed=3, pieces=8)
    room.delete_geometry("ceiling")
    for name in [n for n in room.geometry if n.startswith("wall_")]:
        wall = room.geometry[name]
        wall.vertices[:, 2] = np.minimum(wall.vertices[:, 2], 1.4)  # the scanner stopped at 1.4 m
    mesh = trimesh.util.concatenate(room.dump())
    mesh.merge_vertices()
    area = float(mesh.area)
    # Right triangles of legs e have area e^2 / 2; subdivide_to_size halves edges until all are shorter than e.
    edge = float(np.sqrt(2.0 * area / faces)) * 2.1  # calibrated: the halving overshoots
    vertices, triangles = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=edge)
    vertices, triangles = _merged(vertices, triangles)
    x, y, z = vertices.T
    rgb = np.stack([0.5 + 0.4 * np.sin(2.1 * x), 0.5 + 0.4 * np.sin(1.7 * y + 1.0), 0.4 + 0.3 * np.cos(3.0 * z)], axis=-1)
    colours = np.rint(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    vertex = np.empty(len(vertices), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1"), ("a", "u1")])
    vertex["x"], vertex["y"], vertex["z"] = x, y, z
    vertex["r"], vertex["g"], vertex["b"], vertex["a"] = colours[:, 0], colours[:, 1], colours[:, 2], 255
    face = np.empty(len(triangles), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"], face["v"] = 3, triangles
    props = "".join(f"property {t} {n}\n" for t, n in [("float", "x"), ("float", "y"), ("float", "z"), ("uchar", "red"), ("uchar", "green"), ("uchar", "blue"), ("uchar", "alpha")])
    header = f"ply\nformat binary_little_endian 1.0\ncomment a stand-in for ScanNet's vh_clean.ply\nelement vertex {len(vertex)}\n{props}"
    header += f"element face {len(face)}\nproperty list uchar int vertex_indices\nend_header\n"
    with path.open("wb") as out:
        out.write(header.encode())
        out.write(vertex.tobytes())
        out.write(face.tobytes())
    return {"vertices": len(vertices), "faces": len(triangles), "bytes": path.stat().st_size}


def _merged(vertices, faces):  # noqa: ANN001, ANN202 - numpy arrays; numpy is imported in the phases only
    """Vertices at the same place merged (subdivision splits shared edges once per face)."""
    import numpy as np

    keys = np.round(vertices / 1e-5).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return vertices[first], inverse.reshape(-1)[faces]


def write_ascii(binary: Path, path: Path) -> None:
    import numpy as np

    from ssga_workspace_mesh.ply_format import parse_header, read_body

    data = binary.read_bytes()
    header = parse_header(data)
    columns = read_body(data, header)
    v, f = columns["vertex"], columns["face"]["vertex_indices"]
    text = data[: header.body].decode().replace("binary_little_endian", "ascii")
    rows = np.column_stack([v["x"], v["y"], v["z"]])
    lines = [text]
    lines.append("\n".join(f"{a:.5f} {b:.5f} {c:.5f} {r} {g} {bb} {al}" for (a, b, c), r, g, bb, al in zip(rows, v["red"], v["green"], v["blue"], v["alpha"], strict=True)))
    lines.append("\n" + "\n".join(f"3 {a} {b} {c}" for a, b, c in f.values.reshape(-1, 3)) + "\n")
    path.write_text("".join(lines))


def phase(name: str, path: Path) -> dict[str, float]:
    """Run one phase here; its times and this process's peak memory."""
    import cv2
    import numpy as np

    from ssga_core import Pose
    from ssga_workspace_mesh.loading import load_mesh_scene
    from ssga_workspace_mesh.plugin import MeshConfig, MeshWorkspaceSource

    cv2.setNumThreads(1)
    out: dict[str, float] = {}
    start = time.perf_counter()
    if name in ("read", "auto"):
        scene, _ = load_mesh_scene(path, up_axis="z" if name == "read" else "auto")
        out["seconds"] = time.perf_counter() - start
        out["faces"] = sum(len(g.faces) for g in scene.geometry.values())
    elif name in ("open", "render"):
        workspace = MeshWorkspaceSource(MeshConfig(path=path, up_axis="z")).open()
        out["seconds"] = time.perf_counter() - start
        out["camera_height"] = workspace.camera_height
        if name == "render":
            import shapely

            rng = np.random.default_rng(0)
            free = workspace.floor_plan.free
            (x0, y0, x1, y1), poses = free.bounds, []
            while len(poses) < 20:
                x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
                if free.contains(shapely.Point(x, y)):
                    poses.append(Pose(x, y, rng.uniform(-np.pi, np.pi), workspace.camera_height))
            workspace.render(poses[0])  # first-call costs out of the way
            wall, cpu = [], []
            for pose in poses:
                t, c = time.perf_counter(), time.process_time()
                view = workspace.render(pose)
                wall.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
            out["render_ms"] = 1000 * float(np.median(wall))
            out["render_cpu_ms"] = 1000 * float(np.median(cpu))
            out["hit_share"] = float(view.valid_depth().mean())
    out["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    status = Path("/proc/self/status")
    if status.exists():
        hwm = next((line for line in status.read_text().splitlines() if line.startswith("VmHWM:")), None)
        if hwm:
            out["vmhwm_mib"] = int(hwm.split()[1]) / 1024.0
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faces", type=int, default=1_500_000)
    parser.add_argument("--ascii", action="store_true", help="Also time reading the same scan written as ASCII PLY.")
    parser.add_argument("--keep", type=Path, help="Write the scan here and keep it (default: a temporary folder).")
    parser.add_argument("--phase", choices=PHASES + MAKE_PHASES, help=argparse.SUPPRESS)
    parser.add_argument("--file", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.phase == "make":
        print(json.dumps(make_scan(args.file, args.faces)))
        return
    if args.phase == "ascii":
        write_ascii(args.file, args.file.with_name("scene_ascii.ply"))
        print("{}")
        return
    if args.phase:
        print(json.dumps(phase(args.phase, args.file)))
        return
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

    def child(name: str, file: Path) -> dict[str, float]:
        command = [sys.executable, __file__, "--phase", name, "--file", str(file), "--faces", str(args.faces)]
        run = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
        if run.returncode:
            print(run.stderr, file=sys.stderr)
            raise SystemExit(run.returncode)
        return json.loads(run.stdout.strip().splitlines()[-1])

    with tempfile.TemporaryDirectory() as folder:
        path = args.keep or Path(folder) / "scene_vh_clean.ply"
        t = time.perf_counter()
        print(json.dumps({"scan": child("make", path), "generated_s": round(time.perf_counter() - t, 1)}), flush=True)
        files = {"binary": path}
        if args.ascii:
            child("ascii", path)
            files["ascii"] = path.with_name("scene_ascii.ply")
        for kind, file in files.items():
            for name in PHASES if kind == "binary" else ("imports", "read"):
                result = child(name, file)
                print(json.dumps({"file": kind, "phase": name, **{k: round(v, 3) for k, v in result.items()}}), flush=True)


if __name__ == "__main__":
    main()
