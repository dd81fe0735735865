"""Stand-in folders of captures for this package's tests."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ssga_core import Pose
from ssga_bench import depth_to_png16, write_json, write_png
from ssga_bench.testing import WallWorkspaceSource


@pytest.fixture
def make_folder():
    """``make_folder(root, n=400, seed=0)``: captures at random free poses of the stand-in
    wall room, with depth and the room's floor plan; returns the captures.jsonl rows."""
    return _make_folder


def _make_folder(root, n=400, seed=0):
    """Captures at random free poses of the stand-in wall room, with depth."""
    wall = WallWorkspaceSource().open()
    rng = np.random.default_rng(seed)
    rows = []
    (root / "images").mkdir(parents=True)
    for k in range(n):
        x, y = rng.uniform(-4, 4, size=2)
        pose = Pose(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
        view = wall.render(pose)
        write_png(root / "images" / f"{k:04d}.png", view.rgb)
        write_png(root / "images" / f"{k:04d}-depth.png", depth_to_png16(view.depth))
        rows.append({"rgb": f"images/{k:04d}.png", "depth": f"images/{k:04d}-depth.png", "x": pose.x, "y": pose.y, "yaw": pose.yaw})
    (root / "captures.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    write_json(root / "floorplan.json", wall.floor_plan.to_json())
    return rows
