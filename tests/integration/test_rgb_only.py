"""Captures without depth (RGB and poses, as a robot records them) run every variant of the paper.

A synthesizer that estimates depth from RGB (midas-warp, synsin) makes the S variants run
where depth-warp cannot; the captures here are renders of a procedural home saved as
RGB only, so no stage can read a depth the folder does not hold.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from ssga_workspace_procedural.plugin import ProceduralConfig, ProceduralWorkspaceSource
from typer.testing import CliRunner

from ssga_core import Pose
from ssga_core.cli import app_with_plugin_commands
from ssga_bench import write_json, write_png

app = app_with_plugin_commands()

PAPER_VARIANTS = ["PDS", "PSD", "SPD", "DSP", "PD", "DS", "SD", "D"]

CONFIG = """
output = "{out}"
variants = {variants}
[workspace]
name = "folder"
path = "{captures}"
[protocol]
cells = 2
test_per_class = 1
[stages]
parser = {{ name = "slico", preset = "coarse" }}
descriptor = {{ name = "dense-sift", bow = {{ k = 16 }} }}
synthesizer = {{ name = "{synthesizer}" }}
[training]
epochs = 6
hidden = 32
synthetic_per_class = 1
"""


def write_rgb_only_captures(root, n=500, seed=3):
    """Renders of procedural home ``seed`` at random free poses: RGB files, poses, the floor plan; no depth."""
    home = ProceduralWorkspaceSource(ProceduralConfig(seed=seed, rooms=3)).open()
    plan = home.floor_plan
    x0, y0, x1, y1 = plan.bounds
    rng = np.random.default_rng(seed)
    rows = []
    (root / "images").mkdir(parents=True)
    while len(rows) < n:
        x, y = rng.uniform((x0, y0), (x1, y1))
        if not plan.can_stand(float(x), float(y)):
            continue
        pose = Pose(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
        name = f"images/{len(rows):04d}.png"
        write_png(root / name, home.render(pose).rgb)
        rows.append({"rgb": name, "x": pose.x, "y": pose.y, "yaw": pose.yaw})
    (root / "captures.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    write_json(root / "floorplan.json", plan.to_json())


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    root = tmp_path_factory.mktemp("rgb-only")
    write_rgb_only_captures(root)
    return root


@pytest.mark.slow
@pytest.mark.parametrize(
    "synthesizer, variants",
    [
        ("midas-warp", PAPER_VARIANTS),
        # synsin costs 30-100x midas-warp per view (its README): one order that synthesizes
        # the real view and one that moves a described one cover both of its paths.
        ("synsin", ["SD", "DS"]),
    ],
)
def test_every_paper_variant_runs_on_captures_without_depth(synthesizer, variants, captures, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    path = tmp_path / "exp.toml"
    path.write_text(CONFIG.format(out=out, variants=json.dumps(variants), captures=captures, synthesizer=synthesizer))
    validated = CliRunner().invoke(app, ["config", "validate", str(path)])
    assert validated.exit_code == 0, validated.output
    result = CliRunner().invoke(app, ["run", str(path)])
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader((out / "results.csv").open()))
    ran = {r["row"] for r in rows if r["group"] == "all" and r["mrr"] not in ("", "nan")}
    for variant in variants:
        assert any(label.endswith(f"({variant})") for label in ran), (variant, sorted(ran))
    assert "Ensemble (RRF)" in ran
    assert len(list((out / "variants").glob("*/gcn.pt"))) == len(variants)


def test_depth_warp_on_the_same_captures_is_refused_before_anything_runs(captures, tmp_path):
    path = tmp_path / "exp.toml"
    path.write_text(CONFIG.format(out=tmp_path / "out", variants='["SD", "D"]', captures=captures, synthesizer="depth-warp"))
    result = CliRunner().invoke(app, ["config", "validate", str(path)])
    assert result.exit_code == 1
    assert "depth" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "out").exists()
