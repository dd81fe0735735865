"""``ssga synthesize``: one image from a moved camera, with depth, holes and a side-by-side picture."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from ssga_core.cli import app_with_plugin_commands
from ssga_core.testing import make_view

app = app_with_plugin_commands()
runner = CliRunner()


@pytest.fixture
def wall(tmp_path):
    """make_view's wall 3 m ahead, as an image and its depth (16-bit millimetres)."""
    view = make_view(seed=1)
    cv2.imwrite(str(tmp_path / "wall.png"), cv2.cvtColor(view.rgb, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(tmp_path / "wall-depth.png"), np.rint(view.depth * 1000).astype(np.uint16))
    return view


def read(path, flags=cv2.IMREAD_UNCHANGED):
    image = cv2.imread(str(path), flags)
    assert image is not None, path
    return image


def test_moving_towards_a_wall_magnifies_it_and_leaves_no_hole(tmp_path, wall):
    out = tmp_path / "out"
    args = ["synthesize", str(tmp_path / "wall.png"), "--depth", str(tmp_path / "wall-depth.png"), "--synthesizer", "depth-warp", "--move", "1,0,0", "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    depth = read(out / "depth.png")
    assert depth.dtype == np.uint16 and np.median(depth[depth > 0]) == pytest.approx(2000, abs=5)  # 3 m wall, 1 m closer
    holes = read(out / "holes.png")
    assert (holes == 0).mean() > 0.95
    side = read(out / "side-by-side.png")
    assert side.shape == (wall.camera.height, 3 * wall.camera.width + 8, 3)


def test_turning_away_leaves_holes_shown_in_magenta(tmp_path, wall):
    out = tmp_path / "out"
    args = ["synthesize", str(tmp_path / "wall.png"), "--depth", str(tmp_path / "wall-depth.png"), "--synthesizer", "depth-warp", "--move", "0,0,60", "--out", str(out)]
    assert runner.invoke(app, args).exit_code == 0
    holes = read(out / "holes.png") > 0
    assert 0.2 < holes.mean() < 0.9
    marked = read(out / "side-by-side.png", cv2.IMREAD_COLOR)[:, -wall.camera.width :]
    assert (marked[holes] == [255, 0, 255]).all()  # BGR magenta


def test_a_synthesizer_that_needs_depth_and_a_bad_move_are_one_line(tmp_path, wall):
    base = ["synthesize", str(tmp_path / "wall.png"), "--synthesizer", "depth-warp", "--out", str(tmp_path / "out")]
    result = runner.invoke(app, [*base, "--move", "1,0,0"])
    assert result.exit_code == 1 and "needs depth" in result.stderr and "Traceback" not in result.output
    result = runner.invoke(app, [*base, "--move", "forward"])
    assert result.exit_code == 1 and "expected FORWARD,LEFT,YAW_DEG" in result.stderr
    assert not (tmp_path / "out").exists()
