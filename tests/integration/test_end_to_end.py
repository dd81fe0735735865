"""The whole method through the CLI, with the real default plugins, at a small scale.

The same path as `ssga demo` and `ssga bench`: a procedural home rendered, the
protocol drawn, SLICO parsing, dense SIFT with the bag of words, depth warping, a GCN
per variant, reciprocal-rank fusion and the report.
"""

from __future__ import annotations

import csv
import json

import pytest
from typer.testing import CliRunner

from ssga_core.cli import app_with_plugin_commands

app = app_with_plugin_commands()

CONFIG = """
output = "{out}"
variants = ["PDS", "PSD", "SPD", "DSP", "PD", "DS", "SD", "D"]
[workspace]
name = "procedural"
seed = 3
rooms = 3
[protocol]
cells = 2
test_per_class = 2
[stages]
parser = {{ name = "slico", preset = "coarse" }}
descriptor = {{ name = "dense-sift", bow = {{ k = 16 }} }}
synthesizer = {{ name = "depth-warp" }}
[training]
epochs = 8
hidden = 32
synthetic_per_class = 2
"""


@pytest.mark.slow
def test_run_builds_trains_fuses_and_reports(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the workspace dataset goes under ./runs
    path = tmp_path / "exp.toml"
    path.write_text(CONFIG.format(out=tmp_path / "out"))
    result = CliRunner().invoke(app, ["run", str(path)])
    assert result.exit_code == 0, result.output
    out = tmp_path / "out"
    rows = list(csv.DictReader((out / "results.csv").open()))
    labels = {r["row"] for r in rows}
    assert {"SIFT-SL (PDS)", "SIFT (D)", "Ensemble (RRF)", "random"} <= labels
    test_views = int(next(r for r in rows if r["group"] == "all")["n"])
    assert test_views == 2 * 12 * 2
    timings = json.loads((out / "timings.json").read_text())
    assert {"parse", "describe", "synthesize", "train"} <= set(timings["work"])
    assert {"real views (parse, describe)", "variants: training graphs, train", "variants: score the query views"} <= set(timings["wall"])
    assert "Ensemble (RRF)" in result.output

    # Swapping the fuser reuses every trained variant.
    checkpoints = {p: p.stat().st_mtime_ns for p in (out / "variants").glob("*/gcn.pt")}
    assert len(checkpoints) == 8
    path.write_text(CONFIG.format(out=tmp_path / "out") + '[fuser]\nname = "borda"\n')
    result = CliRunner().invoke(app, ["run", str(path)])
    assert result.exit_code == 0, result.output
    assert "Ensemble (Borda)" in result.output
    assert {p: p.stat().st_mtime_ns for p in checkpoints} == checkpoints


@pytest.mark.slow
def test_bench_runs_each_seed_and_summarises(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "bench.toml"
    config = CONFIG.format(out=tmp_path / "bench").replace(
        'variants = ["PDS", "PSD", "SPD", "DSP", "PD", "DS", "SD", "D"]', 'variants = ["PD", "DS"]'
    )
    path.write_text(config.replace("test_per_class = 2", "test_per_class = 1"))
    result = CliRunner().invoke(app, ["bench", str(path), "--seeds", "1,2"])
    assert result.exit_code == 0, result.output
    summary = (tmp_path / "bench" / "bench.md").read_text()
    assert "## Mean over seeds 1, 2 (± 95% t-interval across seeds)" in summary
    assert "| ensemble − variant | seed 1 L2 | seed 1 L3 | seed 2 L2 | seed 2 L3 |" in summary
    assert "| parse |" in summary and "| **wall** |" in summary
    data = json.loads((tmp_path / "bench" / "bench.json").read_text())
    assert set(data) == {"1", "2"}
    # Each seed is its own home: the protocol and the workspace take the seed.
    homes = {json.loads(p.read_text())["workspace"] for p in (tmp_path / "runs" / "workspaces").glob("*/dataset.json")}
    assert homes == {"procedural-1", "procedural-2"}
