"""Table 1 on a room of real third-party textures, levelled as a scan would need.

Writes the room the mesh plugin's end-to-end test builds from pybullet's textured assets
(``plugins/workspaces/ssga-workspace-mesh/tests/test_real_mesh.py``: a 5 x 4 m room, a
table with a tray, a duck, a bookcase), turned 25 degrees off level, and an experiment
that runs it with the demo's stages and ``up_axis = "auto"``; then ``ssga run`` it:

    .venv/bin/python scripts/real_room.py runs/real-room
    .venv/bin/ssga run runs/real-room/exp.toml

Needs ``pybullet`` (requirements-dev.txt), whose wheel ships the assets.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import trimesh
from ssga_workspace_mesh.loading import save_mesh_scene

ROOT = Path(__file__).resolve().parents[1]
TEST = ROOT / "plugins/workspaces/ssga-workspace-mesh/tests/test_real_mesh.py"
EXPERIMENT = """preset = "demo"
output = "{out}"
[workspace]
name = "mesh"
path = "room.glb"
up_axis = "auto"
[protocol]
cell_size = 1.0
"""


def main(folder: Path) -> None:
    spec = importlib.util.spec_from_file_location("test_real_mesh", TEST)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # the room is built in one place: the test
    scene = module.pybullet_room()
    scene.apply_transform(trimesh.transformations.rotation_matrix(math.radians(25.0), [1.0, 2.0, 0.5]))
    folder.mkdir(parents=True, exist_ok=True)
    save_mesh_scene(scene, folder / "room.glb", up_axis="z")
    (folder / "exp.toml").write_text(EXPERIMENT.format(out=(folder / "out").as_posix()))
    print(f"wrote {folder / 'room.glb'} and {folder / 'exp.toml'}")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "runs/real-room"))
