"""Experiment configs: shape, stage parameters, variants and bindings; every problem at once."""

from __future__ import annotations

import json
import textwrap

import pytest

from ssga_core import ConfigError, SsgaError
from ssga_bench.config import load_experiment, validate_experiment
from ssga_core.config import format_loc

GLB_HEADER = b"glTF" + (2).to_bytes(4, "little") + (12).to_bytes(4, "little")
"""A binary glTF's 12-byte header alone: enough for validation, which reads only the header, to take the file for one."""

BASE = {
    "workspace": {"name": "test-wall"},
    "stages": {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-patch-colour"}, "synthesizer": {"name": "test-shift"}},
    "fuser": {"name": "test-fuser"},
}


@pytest.fixture
def registry(ssga_plugin_set):
    from ssga_core import Fuser, hookimpl
    from ssga_bench import testing as stand_in_workspaces
    from ssga_core.testing import stages as stand_in_stages

    class TestFuser(Fuser):
        name = "test-fuser"

        def _fuse(self, scores):
            return scores.sum(axis=0)

    class Fusers:
        @hookimpl
        def ssga_register_fusers(self):
            return [TestFuser]

    ssga_plugin_set.register(stand_in_stages, "stand-ins")
    ssga_plugin_set.register(stand_in_workspaces, "stand-in-workspaces")
    ssga_plugin_set.register(Fusers(), "fusers")
    return ssga_plugin_set.registry()


def test_the_papers_eight_variants_from_one_list(registry):
    exp = validate_experiment({**BASE, "variants": ["PDS", "PSD", "SPD", "DSP", "PD", "DS", "SD", "D"]}, registry)
    assert [v.label for v in exp.variants] == [
        "PC-ST (PDS)", "PC-ST (PSD)", "PC-ST (SPD)", "PC-ST (DSP)", "PC-ST (PD)", "PC (DS)", "PC (SD)", "PC (D)",
    ]
    # Only the stages an order uses are bound.
    assert set(exp.variants[7].stages) == {"descriptor"}
    graph_maker = exp.variants[0].bind()
    assert graph_maker.parser is not None and graph_maker.synthesizer is not None


def test_two_presets_of_one_order_and_a_free_label(registry):
    exp = validate_experiment(
        {
            **BASE,
            "variants": [
                {"variant": "SPD1"},
                {"variant": "SPD2", "parser": {"name": "test-stripes", "stripes": 8}},
                {"variant": "SD", "label": "CNN", "descriptor": {"name": "test-region-colour"}},
            ],
        },
        registry,
    )
    assert [v.label for v in exp.variants] == ["PC-ST (SPD1)", "PC-ST (SPD2)", "CNN"]
    assert exp.variants[1].stages["parser"].config.stripes == 8
    assert exp.variants[0].stages["parser"].config.stripes == 4


def test_swapping_the_descriptor_of_every_variant_is_one_line(registry):
    swapped = {**BASE, "stages": {**BASE["stages"], "descriptor": {"name": "test-region-colour"}}, "variants": ["PD", "SD"]}
    exp = validate_experiment(swapped, registry)
    assert {v.stages["descriptor"].cls.name for v in exp.variants} == {"test-region-colour"}


def test_all_problems_are_reported_at_once_with_paths(registry):
    bad = {
        **BASE,
        "stages": {**BASE["stages"], "parser": {"name": "test-stripes", "stripes": 0}},
        "variants": [
            "PDS",
            {"variant": "PPD"},
            {"variant": "DSP", "descriptor": {"name": "test-region-colour"}},
            {"variant": "PD", "descriptor": {"name": "sift"}},
            {"variant": "SD", "synthesizer": {"name": "test-shift", "radius": 2}},
        ],
    }
    with pytest.raises(ConfigError) as info:
        validate_experiment(bad, registry, source="exp.toml")
    problems = info.value.problems
    assert problems == [
        "stages.parser.stripes: Input should be greater than or equal to 1",
        "variants[1].variant: invalid variant 'PPD': column 2: stage P (parse) appears twice; each stage runs at most once",
        "variants[2]: DSP cannot use descriptor 'test-region-colour': the real image's description is carried into "
        "the synthetic view, which moves local features at pixel positions with the synthesizer's point map, and "
        "'test-region-colour' gives no local-features",
        "variants[3].descriptor.name: no descriptor named 'sift'; known descriptors: test-patch-colour, test-region-colour",
        "variants[4].synthesizer.radius: unknown key (misspelled?)",
    ]
    assert str(info.value).startswith("exp.toml: 5 problems\n")


def test_shape_errors_come_from_step_one_with_paths(registry):
    with pytest.raises(ConfigError) as info:
        validate_experiment({"workspace": {}, "variants": [], "training": {"epochs": -1, "lr": "fast"}, "extra": 1}, registry)
    assert info.value.problems == [
        "variants: List should have at least 1 item after validation, not 0",
        "workspace.name: Field required",
        "training.epochs: Input should be greater than 0",
        "training.lr: Input should be a valid number, unable to parse string as a number",
        "extra: unknown key (misspelled?)",
    ]


def test_a_variant_needing_an_unbound_stage(registry):
    config = {**BASE, "stages": {"descriptor": {"name": "test-patch-colour"}}, "variants": ["D", "PD"]}
    with pytest.raises(ConfigError) as info:
        validate_experiment(config, registry)
    assert info.value.problems == ["variants[1].parser: PD needs a parser; bind one here or in [stages]"]


def test_duplicate_labels_are_refused(registry):
    with pytest.raises(ConfigError, match=r"variants\[1\].variant: label 'PC-ST \(SPD\)' is also variants\[0\]'s"):
        validate_experiment({**BASE, "variants": ["SPD", "SPD"]}, registry)


def test_presets(registry, monkeypatch):
    from ssga_core.testing.stages import StripesParser

    monkeypatch.setattr(StripesParser, "presets", {"fine": {"stripes": 16}})
    config = {**BASE, "stages": {**BASE["stages"], "parser": {"name": "test-stripes", "preset": "fine"}}, "variants": ["PD"]}
    assert validate_experiment(config, registry).variants[0].stages["parser"].config.stripes == 16
    config["stages"]["parser"]["preset"] = "coarse"
    with pytest.raises(ConfigError, match="stages.parser.preset: parser 'test-stripes' has no preset 'coarse'; its presets: fine"):
        validate_experiment(config, registry)


def test_views_that_lack_what_a_stage_needs(registry, monkeypatch):
    from ssga_core import Data
    from ssga_bench.testing import WallWorkspaceSource

    monkeypatch.setattr(WallWorkspaceSource, "produces", frozenset({Data.RGB}))
    with pytest.raises(ConfigError, match=r"variants\[0\]: SD: synthesizer 'test-shift' needs depth, which the real view does not carry"):
        validate_experiment({**BASE, "variants": ["SD"]}, registry)


def test_loading_files(tmp_path, registry):
    path = tmp_path / "exp.toml"
    path.write_text(
        textwrap.dedent(
            """
            variants = ["PD", "SPD"]
            [workspace]
            name = "test-wall"
            [stages]
            parser = { name = "test-stripes", stripes = 6 }
            descriptor = { name = "test-patch-colour" }
            synthesizer = { name = "test-shift" }
            [fuser]
            name = "test-fuser"
            """
        )
    )
    exp = load_experiment(path, registry)
    assert exp.source == str(path) and len(exp.variants) == 2
    path.write_text("variants = [")
    with pytest.raises(SsgaError, match=r"exp.toml: not valid TOML: "):
        load_experiment(path, registry)
    with pytest.raises(SsgaError, match="missing.toml: no such config file"):
        load_experiment(tmp_path / "missing.toml", registry)


def test_format_loc():
    assert format_loc(("variants", 2, "descriptor", "k")) == "variants[2].descriptor.k"
    assert format_loc(()) == "(top level)"


def test_relative_paths_in_stage_parameters_follow_the_config_file(tmp_path, registry, ssga_plugin_set):
    from pathlib import Path

    from ssga_core import StageConfig
    from ssga_bench.testing import WallWorkspaceSource, plugin_with

    class MeshConfig(StageConfig):
        mesh: Path

    class MeshSource(WallWorkspaceSource):
        name = "test-mesh"
        Config = MeshConfig

    ssga_plugin_set.register(plugin_with(MeshSource, hook="ssga_register_workspaces"), "mesh")  # beside the stand-ins the `registry` fixture registered
    with_mesh = ssga_plugin_set.registry()
    (tmp_path / "sub").mkdir()
    path = tmp_path / "sub" / "exp.toml"
    for given, expected in (("house.glb", tmp_path / "sub" / "house.glb"), ("/abs/house.glb", Path("/abs/house.glb"))):
        path.write_text(
            f'variants = ["D"]\n[workspace]\nname = "test-mesh"\nmesh = "{given}"\n'
            '[stages]\ndescriptor = { name = "test-patch-colour" }\n[fuser]\nname = "test-fuser"\n'
        )
        assert load_experiment(path, with_mesh).workspace.config.mesh == expected


def test_a_packaged_experiment_by_name_and_as_a_preset(tmp_path, ssga_installed_registry, monkeypatch):
    from ssga_bench.config import config_path, packaged_presets

    monkeypatch.chdir(tmp_path)
    assert {"demo", "bench", "paper"} <= set(packaged_presets())
    assert config_path("paper").name == "paper.toml" and config_path("paper").exists()
    paper = load_experiment("paper", ssga_installed_registry)
    assert [v.label for v in paper.variants] == [
        "CNN", "P (DS)", "P (SD)", "P-SL (PDS)", "P-SL (PSD)", "P-SL (SPD1)", "P-SL (SPD2)",
        "P-SE (PDS)", "P-SE (PSD)", "P-DE (PDS)", "P-DE (PSD)", "GIST (SD2)",
    ]
    # On one's own workspace: the preset's rows and training, this file's workspace and protocol.
    (tmp_path / "mine.toml").write_text('preset = "paper"\noutput = "runs/mine"\n[workspace]\nname = "procedural"\nseed = 7\n[protocol]\ncells = 3\n')
    mine = load_experiment("mine.toml", ssga_installed_registry)
    assert [v.label for v in mine.variants] == [v.label for v in paper.variants]
    assert mine.workspace.config.seed == 7 and mine.workspace.config.rooms == 8  # merged: same plugin
    assert mine.config.protocol.cells == 3 and mine.config.protocol.test_per_class == 12
    assert str(mine.config.output) == "runs/mine" and mine.config.training == paper.config.training
    assert mine.config.training.classifier == "graph-match" and mine.config.training.synthetic_per_class == 12
    # A section naming another plugin replaces the preset's (the procedural keys would not validate).
    (tmp_path / "scan.glb").write_bytes(GLB_HEADER)
    (tmp_path / "other.toml").write_text('preset = "demo"\n[workspace]\nname = "mesh"\npath = "scan.glb"\n')
    other = load_experiment("other.toml", ssga_installed_registry)  # merged, the procedural keys would be errors
    assert other.workspace.name == "mesh" and [v.label for v in other.variants][0] == "SIFT-SL (PDS)"
    (tmp_path / "bad.toml").write_text('preset = "papers"\n')
    with pytest.raises(ConfigError, match="'papers' is not a packaged experiment; known: bench, demo, paper"):
        load_experiment("bad.toml", ssga_installed_registry)


def test_the_configs_in_docs_config_md_validate(tmp_path, ssga_installed_registry, monkeypatch):
    """Every ```toml block of docs/config.md marked `# docs-check: NAME` is a whole config that validates."""
    import re
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "config.md").read_text()
    blocks = re.findall(r"```toml\n# docs-check: (\S+)\n(.*?)```", text, flags=re.S)
    assert {name for name, _ in blocks} >= {"swap-all", "swap-one", "paper-on-my-scan"}
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my-scan.glb").write_bytes(GLB_HEADER)
    labels = {}
    for name, body in blocks:
        (tmp_path / f"{name}.toml").write_text(body)
        labels[name] = [v.label for v in load_experiment(tmp_path / f"{name}.toml", ssga_installed_registry).variants]
    *swapped, own = labels["swap-all"]
    assert swapped[0] == "P-SL (PDS)" and all(label.startswith("P") for label in swapped)
    assert own == "GIST (SD2)", "a variant that binds its own descriptor keeps it"
    assert labels["swap-one"] == ["SIFT-SL (PDS)", "SIFT (DS)", "CNN"]
    assert labels["paper-on-my-scan"][0] == "CNN"


def test_ssga_variants_reads_configs_as_every_command_does(tmp_path, monkeypatch):
    """A packaged experiment by name, and a file of one's own on a preset with one stage swapped."""
    from typer.testing import CliRunner

    from ssga_core.cli import app_with_plugin_commands

    monkeypatch.chdir(tmp_path)
    app, runner = app_with_plugin_commands(), CliRunner()
    result = runner.invoke(app, ["variants", "--config", "parsers", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.output)
    assert [(r["label"], r["parser"]) for r in rows[:3]] == [("SIFT-SL (PDS)", "slico"), ("SIFT-SL (PSD)", "slico"), ("SIFT-SE (PDS)", "cascade-seg")]
    (tmp_path / "mine.toml").write_text('preset = "bench"\n[stages]\nparser = { name = "semantic" }\n')
    result = runner.invoke(app, ["variants", "--config", "mine.toml", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.output)
    assert len(rows) == 10 and rows[0] == {"label": "SIFT-GT (PDS)", "variant": "PDS", "parser": "semantic", "descriptor": "dense-sift", "synthesizer": "depth-warp"}
    # A variant that names its own descriptor keeps it when the file swaps another stage.
    assert rows[-2:] == [
        {"label": "GIST (SD2)", "variant": "SD2", "parser": None, "descriptor": "gist", "synthesizer": "depth-warp"},
        {"label": "DL (SD3)", "variant": "SD3", "parser": None, "descriptor": "depth-layout", "synthesizer": "depth-warp"},
    ]
    result = runner.invoke(app, ["variants", "--config", "nosuch"])
    assert result.exit_code != 0 and "nosuch: no such config file" in result.output


def test_a_preset_may_stand_on_another(tmp_path, ssga_installed_registry, monkeypatch):
    """``parsers`` stands on ``bench``: a file on ``parsers`` gets both, its own keys on top."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.toml").write_text('preset = "parsers"\n[stages]\ndescriptor = { name = "pnv" }\n')
    mine = load_experiment("mine.toml", ssga_installed_registry)
    assert [v.label for v in mine.variants][:3] == ["P-SL (PDS)", "P-SL (PSD)", "P-SE (PDS)"]
    assert mine.workspace.config.rooms == 8 and mine.config.protocol.cells == 10  # bench's, through parsers


def test_a_preset_that_names_itself_is_refused(tmp_path, monkeypatch):
    from ssga_bench import config

    (tmp_path / "a.toml").write_text('preset = "b"\n')
    (tmp_path / "b.toml").write_text('preset = "a"\n')
    monkeypatch.setattr(config, "packaged_presets", lambda: ["a", "b"])
    monkeypatch.setattr(config, "packaged_config", lambda name: tmp_path / name)
    with pytest.raises(ConfigError, match="'a' names itself through a -> b -> a"):
        config.with_preset({"preset": "a"}, "mine.toml")
