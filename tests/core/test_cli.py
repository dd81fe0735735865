"""The ssga command, through typer's CliRunner."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from ssga_core.cli import app_with_plugin_commands

app = app_with_plugin_commands()

runner = CliRunner()

CONFIG = """
variants = ["PDS", "DSP", {variant = "SPD2", parser = {name = "test-stripes", stripes = 8}}]
[workspace]
name = "test-wall"
[stages]
parser = { name = "test-stripes" }
descriptor = { name = "test-patch-colour" }
synthesizer = { name = "test-shift" }
[fuser]
name = "rrf"
"""


def test_variants_list_shows_every_order_and_the_papers_eight():
    result = runner.invoke(app, ["variants", "--list"])
    assert result.exit_code == 0, result.output
    rows = [line for line in result.output.splitlines() if line.startswith("│")]
    assert len(rows) == 11
    assert sum(" yes " in row for row in rows) == 8
    dsp = next(row for row in rows if row.startswith("│ DSP "))
    assert "describe → synthesize → parse" in dsp and "descriptor: local-features" in dsp


def test_variants_json_has_needs_and_equivalences():
    result = runner.invoke(app, ["variants", "--json"])
    rows = {row["order"]: row for row in json.loads(result.output)}
    assert rows["SDP"]["equivalent_to"] == ["SPD"] and not rows["SDP"]["in_paper"]
    assert rows["DS"]["needs"] == {"descriptor": ["local-features"], "synthesizer": ["point-map"]}
    assert rows["SPD"]["query_path"] == "PD"


def test_variants_of_a_config(tmp_path, stand_ins):
    path = tmp_path / "exp.toml"
    path.write_text(CONFIG)
    result = runner.invoke(app, ["variants", "--config", str(path), "--json"])
    assert result.exit_code == 0, result.output
    labels = [r["label"] for r in json.loads(result.output)]
    assert labels == ["PC-ST (PDS)", "PC-ST (DSP)", "PC-ST (SPD2)"]


def test_plugins_json_lists_distributions_and_config_schemas():
    result = runner.invoke(app, ["plugins", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    grid = next(p for p in data["plugins"] if p["name"] == "grid")
    assert grid["distribution"] == "ssga-parser-grid" and grid["kind"] == "parser"
    assert set(grid["config_schema"]["properties"]) == {"rows", "cols"}
    assert grid["presets"] == ["coarse", "fine"]
    assert grid["layouts"] == []  # not a learned stage
    assert data["failures"] == []
    pnv = next(p for p in data["plugins"] if p["name"] == "pnv")
    assert [layout["name"] for layout in pnv["layouts"]] == ["light", "vgg16"]
    assert "mapillary_WPCA" in pnv["layouts"][1]["source"]


def test_plugins_table():
    result = runner.invoke(app, ["plugins"])
    assert result.exit_code == 0
    assert "ssga-parser-grid" in result.output and "rows=4, cols=4" in result.output


def test_config_validate_ok(tmp_path, stand_ins):
    path = tmp_path / "exp.toml"
    path.write_text(CONFIG)
    result = runner.invoke(app, ["config", "validate", str(path)])
    assert result.exit_code == 0, result.output
    assert "ok, 3 variants: PC-ST (PDS), PC-ST (DSP), PC-ST (SPD2)" in result.output


def test_config_validate_reports_every_problem_without_a_traceback(tmp_path, stand_ins):
    path = tmp_path / "bad.toml"
    path.write_text(CONFIG.replace('"DSP"', '"DPP"').replace("stripes = 8", "stripes = -1"))
    result = runner.invoke(app, ["config", "validate", str(path)])
    assert result.exit_code == 1
    assert "Traceback" not in result.output
    lines = result.stderr.splitlines()
    assert lines[0] == f"error: {path}: 2 problems"
    assert lines[1].strip().startswith("variants[1].variant: invalid variant 'DPP': column 3")
    assert lines[2].strip() == "variants[2].parser.stripes: Input should be greater than or equal to 1"


@pytest.mark.parametrize(
    ("content", "message"),
    [(None, "no such config file"), ("[workspace", "not valid TOML")],
)
def test_unreadable_configs_are_one_line_errors(tmp_path, content, message):
    path = tmp_path / "exp.toml"
    if content is not None:
        path.write_text(content)
    result = runner.invoke(app, ["config", "validate", str(path)])
    assert result.exit_code == 1
    assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr


def test_config_schema_lists_installed_plugins():
    result = runner.invoke(app, ["config", "schema"])
    assert result.exit_code == 0
    schema = json.loads(result.output)
    parsers = schema["$defs"]["ParserRef"]["oneOf"]
    grid = next(p for p in parsers if p["properties"]["name"] == {"const": "grid"})
    assert grid["properties"]["preset"] == {"enum": ["coarse", "fine"]}
    assert "rows" in grid["properties"]
    assert {f["properties"]["name"]["const"] for f in schema["$defs"]["FuserRef"]["oneOf"]} >= {"rrf", "borda", "mean-prob"}


def test_no_arguments_shows_help():
    result = runner.invoke(app, [])
    assert "variants" in result.output and "plugins" in result.output


def test_workspace_build_and_show(tmp_path, stand_ins):
    out = tmp_path / "ws"
    args = ["workspace", "build", "--source", "test-wall", "--option", "size=8", "--cells", "2", "--test-per-class", "2", "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    # 2 per class, then on (up to 4) while a level is short of the demo's 100: every level is, so the classes
    # fill to their cap (the test wall has no L3 views).
    assert f"{out}: 24 classes, 2 real training views, 96 test views (L1 75, L2 20, L3 1)" in result.output
    # A second build finds everything done; other settings are refused without --overwrite.
    assert runner.invoke(app, args).exit_code == 0
    result = runner.invoke(app, [*args[:-2], "--seed", "9", "--out", str(out)])
    assert result.exit_code == 1 and "holds a dataset built with other settings (protocol, source, workspace)" in result.stderr
    result = runner.invoke(app, ["workspace", "show", str(out), "--by", "level"])
    assert result.exit_code == 0, result.output
    import cv2

    plan = cv2.imread(str(out / "birdseye-by-level.png"))
    sheet = cv2.imread(str(out / "contact-sheet.png"))
    assert plan.shape[0] > 400 and sheet.shape[1] > 128
    # The plan is mostly light floor with dark walls around it.
    assert (plan.mean(axis=2) < 100).mean() > 0.01


def test_workspace_build_rejects_bad_options(stand_ins, tmp_path):
    result = runner.invoke(app, ["workspace", "build", "--source", "test-wall", "--option", "size", "--out", str(tmp_path)])
    assert result.exit_code == 1 and "expected key=value" in result.stderr
    result = runner.invoke(app, ["workspace", "build", "--source", "test-wall", "-o", "size=0.5", "--out", str(tmp_path)])
    assert result.exit_code == 1 and "workspace.size: Input should be greater than 1" in result.stderr
    result = runner.invoke(app, ["workspace", "show", str(tmp_path / "none")])
    assert result.exit_code == 1 and "not an ssga dataset" in result.stderr
