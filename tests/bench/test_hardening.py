"""The benchmark layer and its commands against bad input and file-system faults.

Everything runs on the stand-in stages and the stand-in wall workspace (a few seconds in all).
A user error is one line on stderr, ``error: ...`` naming the path or the input, exit 1,
no traceback, and no file half-written; damaged outputs are recomputed with a warning.
"""

from __future__ import annotations

import errno
import json
import os
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
import typer.main
from typer.testing import CliRunner

import ssga_bench.io
from ssga_bench.config import validate_experiment
from ssga_bench.dataset_build import build_dataset
from ssga_bench.experiment import folder_names, run_experiment
from ssga_bench.io import OutputError, atomic_write_bytes
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.testing import WallWorkspaceSource, cli_error_line, plugin_with, read_only_below, snapshot
from ssga_core.cli import app_with_plugin_commands
from ssga_core.errors import ConfigError

app = app_with_plugin_commands()
runner = CliRunner()

STAGES = {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-patch-colour"}, "synthesizer": {"name": "test-shift"}}
SMALL = ProtocolConfig(cells=2, test_per_class=1, seed=4)

CONFIG = """
variants = ["PDS", "PD"]
[workspace]
name = "test-wall"
size = 8
[protocol]
cells = 2
test_per_class = 1
[stages]
parser = { name = "test-stripes" }
descriptor = { name = "test-patch-colour" }
synthesizer = { name = "test-shift" }
[fuser]
name = "rrf"
[training]
epochs = 3
hidden = 16
"""

BUILD = ["workspace", "build", "--source", "test-wall", "--option", "size=8", "--cells", "2", "--test-per-class", "1"]


@pytest.fixture
def workdir(tmp_path, monkeypatch, stand_ins):
    """The stand-ins, run from ``tmp_path`` (so the default ``runs/`` lands there), with ``exp.toml``."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "exp.toml").write_text(CONFIG)
    return tmp_path


def invoke(*args: str):
    return runner.invoke(app, [str(a) for a in args])


def one_line_error(result, *names: str) -> str:
    """The one ``error:`` line of a failed command, checked: no traceback, names each of ``names``."""
    # Progress bars and "variant ..." lines may come before it on stderr.
    return cli_error_line(result, *names, passing=("variant ",))


def stand_in_experiment(registry, variants=("PDS", "PD")):
    return validate_experiment(
        {"workspace": {"name": "test-wall"}, "stages": STAGES, "variants": list(variants), "fuser": {"name": "rrf"}, "training": {"epochs": 3, "hidden": 16}},
        registry,
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds")
    return build_dataset(WallWorkspaceSource().open(), out, source={"name": "test-wall"}, protocol=SMALL)


# --- 1. `workspace build --overwrite` deletes only what ssga wrote ---


def test_overwrite_replaces_only_ssgas_files(workdir):
    out = workdir / "ws"
    assert invoke(*BUILD, "--out", out).exit_code == 0
    old_ids = {json.loads(line)["id"] for line in (out / "manifest.jsonl").read_text().splitlines()}
    (out / "notes.txt").write_text("my notes")
    (out / "rgb" / "mine.png").write_bytes(b"my picture")
    (out / "mine").mkdir()
    (out / "mine" / "data.csv").write_text("1,2\n")

    result = invoke(*BUILD, "--seed", "9", "--out", out, "--overwrite")
    assert result.exit_code == 0, result.output
    assert json.loads((out / "dataset.json").read_text())["protocol"]["seed"] == 9
    # The user's files stay, byte for byte.
    assert (out / "notes.txt").read_text() == "my notes"
    assert (out / "rgb" / "mine.png").read_bytes() == b"my picture"
    assert (out / "mine" / "data.csv").read_text() == "1,2\n"
    # Every other image is a view of the new plan: the old plan's were deleted.
    new_ids = {json.loads(line)["id"] for line in (out / "manifest.jsonl").read_text().splitlines()}
    assert new_ids != old_ids
    assert {p.stem for p in (out / "rgb").iterdir()} == new_ids | {"mine"}


@pytest.mark.parametrize(
    "plan",
    [
        "{not json",
        "[]",
        '{"samples": [{"no id": 1}]}',
        # Ids that are no file ssga wrote: deleting "rgb/<id>.png" would hit the user's files.
        '{"samples": [{"id": "../notes"}, {"id": "../../outside"}]}',
    ],
)
def test_overwrite_refuses_a_damaged_plan_and_deletes_nothing(workdir, plan):
    out = workdir / "ws"
    assert invoke(*BUILD, "--out", out).exit_code == 0
    (out / "plan.json").write_text(plan)
    (out / "notes.png").write_text("mine")
    (workdir / "outside.png").write_text("mine too")
    before = snapshot(workdir)
    result = invoke(*BUILD, "--seed", "9", "--out", out, "--overwrite")
    one_line_error(result, out / "plan.json", "damaged")
    assert snapshot(workdir) == before


@pytest.mark.parametrize("header", ["[]", '{"format": 1}', '{"format": 1, "workspace": "w", "protocol": {"cells": -1}, "camera": {}}'])
def test_a_damaged_dataset_header_is_one_line(workdir, header):
    out = workdir / "ws"
    assert invoke(*BUILD, "--out", out).exit_code == 0
    (out / "dataset.json").write_text(header)
    before = snapshot(workdir)
    one_line_error(invoke("workspace", "show", out), out / "dataset.json")
    # Refused without --overwrite; a dataset.json without ssga's "format" key is not ssga's, and refused with it too.
    one_line_error(invoke(*BUILD, "--out", out), out, "other settings" if header != "[]" else "not written by ssga")
    assert snapshot(workdir) == before


def test_a_damaged_manifest_is_one_line(workdir):
    out = workdir / "ws"
    assert invoke(*BUILD, "--out", out).exit_code == 0
    (out / "manifest.jsonl").write_text("[1, 2]\n")
    one_line_error(invoke("workspace", "show", out), out / "manifest.jsonl")


# --- 4. File-system failures: one line naming the path, nothing half-written ---


def test_run_into_an_output_that_is_a_file(workdir):
    (workdir / "x").write_text("mine")
    one_line_error(invoke("run", "exp.toml", "--output", "x"), "x: cannot create the folder: a file is in the way")
    assert (workdir / "x").read_text() == "mine"
    assert not (workdir / "runs").exists()  # refused before the workspace was built


@pytest.mark.parametrize(("out", "why"), [("f", "is a file"), ("f/sub", "Not a directory")])
def test_workspace_build_into_a_file(workdir, out, why):
    (workdir / "f").write_text("mine")
    one_line_error(invoke(*BUILD, "--out", out), out, why)
    assert (workdir / "f").read_text() == "mine"


def failing(error: int, under: Path, real):
    """``real``, except for paths under ``under``, where it raises ``OSError(error)``."""

    def fail(*args, **kwargs):
        target = kwargs.get("dir", args[1] if len(args) > 1 else None)  # mkstemp(dir=...), replace(src, dst)
        if target is not None and Path(target).resolve().is_relative_to(under.resolve()):
            raise OSError(error, os.strerror(error), str(target))
        return real(*args, **kwargs)

    return fail


FAULTS = [("tempfile.mkstemp", errno.EROFS), ("os.replace", errno.ENOSPC), ("os.replace", errno.EROFS)]


@pytest.mark.parametrize(("where", "error"), FAULTS)
def test_atomic_write_fails_whole(tmp_path, monkeypatch, where, error):
    module, name = where.split(".")
    target = {"tempfile": tempfile, "os": os}[module]
    monkeypatch.setattr(target, name, failing(error, tmp_path, getattr(target, name)))
    (tmp_path / "a.bin").write_bytes(b"old")
    with pytest.raises(OutputError) as info:
        atomic_write_bytes(tmp_path / "a.bin", b"new")
    assert str(info.value) == f"{tmp_path / 'a.bin'}: cannot write: {os.strerror(error)}"
    assert snapshot(tmp_path) == {"a.bin": b"old"}  # no .tmp file left beside it


@pytest.mark.parametrize(("where", "error"), FAULTS[:2])
def test_run_into_a_folder_where_writes_fail(workdir, monkeypatch, where, error):
    module, name = where.split(".")
    target = {"tempfile": tempfile, "os": os}[module]
    out = workdir / "out"
    monkeypatch.setattr(target, name, failing(error, out, getattr(target, name)))
    line = one_line_error(invoke("run", "exp.toml", "--output", out), out, os.strerror(error))
    assert re.match(rf"error: {re.escape(str(out))}/\S+: cannot write: ", line)
    written = snapshot(out)
    assert not any(name.endswith(".tmp") for name in written) and "report.md" not in written


def test_a_finished_read_only_dataset_is_reused_without_writing(workdir, monkeypatch):
    assert invoke("workspace", "build", "--config", "exp.toml").exit_code == 0
    (folder,) = (workdir / "runs" / "workspaces").iterdir()
    before = snapshot(folder)
    monkeypatch.setattr("ssga_bench.io.atomic_write_bytes", read_only_below(folder, ssga_bench.io.atomic_write_bytes))
    result = invoke("workspace", "build", "--config", "exp.toml")
    assert result.exit_code == 0, result.output
    result = invoke("run", "exp.toml", "--output", "out")
    assert result.exit_code == 0, result.output
    assert (workdir / "out" / "report.md").exists()
    assert snapshot(folder) == before


def test_a_read_only_working_directory_for_the_default_runs_folder(workdir, monkeypatch):
    real = Path.mkdir

    def mkdir(self, *args, **kwargs):
        if "runs" in self.parts:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    line = one_line_error(invoke(*BUILD), "runs/workspaces/test-wall-0-", "cannot create the folder: Permission denied")
    assert line.startswith("error: runs/workspaces/")
    one_line_error(invoke("run", "exp.toml"), "runs/experiment: cannot create the folder: Permission denied")
    assert not (workdir / "runs").exists()


# --- 6. Validation refuses what cannot run ---


@pytest.mark.parametrize(
    ("section", "key", "value", "toml"),
    [
        ("protocol", "seed", -1, "-1"),
        ("training", "seed", -1, "-1"),
        ("protocol", "cell_size", 1e-9, "1e-9"),
        ("training", "jitter_m", float("inf"), "inf"),
        ("training", "hidden", 10**12, "1000000000000"),
        ("protocol", "test_radius", float("nan"), "nan"),
    ],
)
def test_validation_refuses_what_cannot_run(stand_ins, workdir, section, key, value, toml):
    data = {"workspace": {"name": "test-wall"}, "stages": STAGES, "variants": ["PD"], section: {key: value}}
    with pytest.raises(ConfigError, match=rf"{section}\.{key}: "):
        validate_experiment(data, stand_ins)
    path = workdir / "bad.toml"
    text = re.sub(rf"(?m)^{key} = .*\n", "", CONFIG)  # the key once, with the bad value
    path.write_text(text.replace(f"[{section}]\n", f"[{section}]\n{key} = {toml}\n", 1))
    result = invoke("config", "validate", path)
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    # A config error is its heading line and one line per problem.
    first, problem = result.stderr.splitlines()
    assert first == f"error: {path}: 1 problem"
    assert problem.strip().startswith(f"{section}.{key}: "), problem


@pytest.mark.parametrize(
    ("args", "names"),
    [
        (["workspace", "build", "--source", "test-wall", "--cells", "0", "--out", "ws"], ["protocol.cells"]),
        (["workspace", "build", "--source", "test-wall", "--cell-size", "nan", "--out", "ws"], ["protocol.cell_size"]),
        (["bench", "exp.toml", "--seeds", "a"], ["--seeds 'a'"]),
        (["bench", "exp.toml", "--seeds", ""], ["--seeds ''"]),
        (["bench", "exp.toml", "--seeds", "1,,2"], ["--seeds '1,,2'"]),
        (["bench", "exp.toml", "--seeds", "1,1"], ["--seeds '1,1'", "repeated"]),
        (["bench", "exp.toml", "--seeds", "²"], ["--seeds '²'"]),
    ],
)
def test_bad_command_line_options_are_refused(workdir, monkeypatch, args, names):
    monkeypatch.setattr("ssga_bench.bench.run", lambda **kw: pytest.fail("ran an experiment"))
    result = invoke(*args)
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    first = result.stderr.splitlines()[0]
    assert first.startswith("error: ")
    assert all(name in result.stderr for name in names), result.stderr
    assert not (workdir / "ws").exists() and not (workdir / "runs").exists()


def test_test_per_class_zero_is_a_usage_error(workdir):
    result = invoke("bench", "exp.toml", "--test-per-class", "0")
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "Invalid value for '--test-per-class'" in result.stderr


def test_bench_checks_every_seed_before_running_any(workdir, monkeypatch):
    # Seed 0 is fine and 2**32 is not: nothing may run before that is known.
    monkeypatch.setattr("ssga_bench.bench.run", lambda **kw: pytest.fail("ran seed 0 before checking the others"))
    result = invoke("bench", "exp.toml", "--seeds", f"0,{2**32}", "--output", "out")
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert result.stderr.lstrip().startswith(f"error: exp.toml (seed {2**32}): 2 problems")
    assert "protocol.seed: Input should be less than 4294967296" in result.stderr
    assert not (workdir / "out").exists()


# --- 7. Damaged run outputs are recomputed, with a warning naming them ---


def test_damaged_outputs_are_recomputed_with_a_warning(tmp_path, dataset, stand_ins, capsys):
    exp = stand_in_experiment(stand_ins)
    report, _ = run_experiment(exp, dataset, tmp_path)
    capsys.readouterr()
    entries = sorted((tmp_path / "cache").rglob("*.npz"))
    truncated, not_npz, wrong_arrays = entries[0], entries[1], entries[-1]
    truncated.write_bytes(truncated.read_bytes()[:40])
    not_npz.write_bytes((tmp_path / "variants" / "PC-ST_PD" / "scores.npy").read_bytes())  # a bare .npy
    with open(wrong_arrays, "wb") as f:
        np.savez(f, other=np.zeros(3))
    pds, pd = tmp_path / "variants" / "PC-ST_PDS" / "scores.npy", tmp_path / "variants" / "PC-ST_PD" / "scores.npy"
    pds.write_bytes(pds.read_bytes()[:60])
    np.save(pd, np.zeros((3, 3)))

    again, _ = run_experiment(exp, dataset, tmp_path)
    err = capsys.readouterr().err
    assert again.markdown() == report.markdown()
    warnings = err.splitlines()
    for path, why in [
        (pds, "damaged scores"),
        (pd, "scores of shape (3, 3)"),
        (truncated, "damaged cache entry"),
        (not_npz, "damaged cache entry (TypeError"),
        (wrong_arrays, "damaged cache entry (KeyError"),
    ]:
        assert any(w.startswith(f"warning: {path}: {why}") for w in warnings), (path, err)
    shape = (len(dataset.split("test")), dataset.num_classes)
    assert np.load(pds).shape == np.load(pd).shape == shape
    for entry in (truncated, not_npz, wrong_arrays):
        with np.load(entry) as data:
            assert "other" not in data.files and len(data.files) >= 2

    # Scores of the right shape that are not numbers are damaged too, not a crash.
    np.save(pd, np.full(shape, "a"))
    third, _ = run_experiment(exp, dataset, tmp_path)
    assert third.markdown() == report.markdown()
    assert f"warning: {pd}: scores of shape {shape} and type <U1" in capsys.readouterr().err


# --- 8. Labels that would share a folder, or leave the output folder ---


def test_folder_names_are_distinct_and_inside():
    labels = ["x y", "x/y", "..", ".", "", "PD", "pd", "P-SL (SPD)"]
    names = folder_names(labels)
    assert len({n.lower() for n in names.values()}) == len(labels)
    assert names["P-SL (SPD)"] == "P-SL_SPD"  # a readable name stays readable
    base = Path("/out/variants")
    for name in names.values():
        assert name and name not in (".", "..") and "/" not in name and not name.startswith(".")
        assert (base / name).resolve().parent == base


def test_a_run_with_such_labels_writes_inside_its_variants_folder(tmp_path, dataset, stand_ins):
    exp = validate_experiment(
        {
            "workspace": {"name": "test-wall"},
            "stages": STAGES,
            "variants": [{"variant": "PD", "label": "x y"}, {"variant": "PDS", "label": "x/y"}, {"variant": "SD", "label": ".."}],
            "fuser": {"name": "rrf"},
            "training": {"epochs": 2, "hidden": 16},
        },
        stand_ins,
    )
    out = tmp_path / "run"
    report, _ = run_experiment(exp, dataset, out)
    assert set(report.variants) == {"x y", "x/y", ".."}
    folders = [p for p in (out / "variants").iterdir()]
    assert len(folders) == 3 and all((p / "scores.npy").exists() for p in folders)
    assert {json.loads((p / "training.json").read_text())["label"] for p in folders} == {"x y", "x/y", ".."}
    assert [p.name for p in tmp_path.iterdir()] == ["run"]
    assert {p.name for p in out.iterdir()} == {"run.json", "cache", "variants", "oracle", "report.md", "results.csv", "results.png", "timings.json", "predictions.jsonl", "pseudo_views.jsonl", "queries", "index.html", "workspace.png", "scene-graphs"}


# --- 9. Output files get the permissions the umask gives ---


@pytest.mark.parametrize(("umask", "mode"), [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_written_files_respect_the_umask(tmp_path, umask, mode):
    old = os.umask(umask)
    try:
        atomic_write_bytes(tmp_path / "a.txt", b"x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == mode


# --- 10. Several configs at once, help texts without holes, variants of a config as JSON ---


def test_config_validate_checks_every_file(workdir):
    good, bad = workdir / "a.toml", workdir / "b.toml"
    good.write_text(CONFIG)
    bad.write_text(CONFIG.replace('"PD"]', '"PDD"]'))
    result = invoke("config", "validate", good, bad)
    assert result.exit_code == 1
    assert result.stdout.strip() == f"{good}: ok, 2 variants: PC-ST (PDS), PC-ST (PD)"
    assert result.stderr.startswith(f"error: {bad}: 1 problem")
    result = invoke("config", "validate", bad, good)  # the order does not matter
    assert result.exit_code == 1 and f"{good}: ok" in result.stdout


def _commands(command, path=()):
    for name, sub in getattr(command, "commands", {}).items():
        yield (*path, name), sub
        yield from _commands(sub, (*path, name))


def test_every_option_has_help_without_holes(workdir):
    root = typer.main.get_command(app)
    commands = dict(_commands(root))
    assert {("workspace", "build"), ("run",), ("bench",)} <= set(commands)
    for path, command in commands.items():
        rendered = invoke(*path, "--help")
        assert rendered.exit_code == 0, (path, rendered.output)
        flat = "".join(rendered.output.split())
        for param in command.params:
            text = getattr(param, "help", None)
            if param.name == "help" or text is None and not hasattr(param, "help"):
                continue
            where = f"ssga {' '.join(path)} {param.name}"
            assert text and text.strip() == text, where
            assert "  " not in text and not re.search(r"\s[.,;:)\]]|[(\[]\s|\(\)|\[\]", text), (where, text)
            # Shown as written: nothing taken for markup and dropped ("[default: ...]").
            assert "".join(text.split()) in flat, (where, text)
        assert not re.search(r"\w  (and|or|the)\b|\s\.\s", rendered.output), (path, rendered.output)


def test_variants_of_a_config_as_json_with_the_orders(workdir):
    result = invoke("variants", "--list", "--config", "exp.toml", "--json")
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert set(data) == {"orders", "variants"}
    assert len(data["orders"]) == 11 and data["orders"][0]["order"] == "PDS"
    assert [v["label"] for v in data["variants"]] == ["PC-ST (PDS)", "PC-ST (PD)"]
    assert data["variants"][1] == {"label": "PC-ST (PD)", "variant": "PD", "parser": "test-stripes", "descriptor": "test-patch-colour", "synthesizer": None}


# --- 10. A variant whose checkpoint is missing is reported as not run; the others run ---


def test_a_variant_without_its_weights_is_reported_not_dropped(tmp_path, dataset, ssga_plugin_set, stand_ins):
    from ssga_bench.learned import Learned, LearnedConfig
    from ssga_core.testing.stages import PatchColour

    class Unweighted(Learned, PatchColour):
        name = "test-unweighted"
        abbrev = "UW"
        Config = type("UnweightedConfig", (LearnedConfig,), {})

        def _extract(self, view):
            self.weights_file()  # the checkpoint is looked up when first needed, as a learned stage does
            return super()._extract(view)

    ssga_plugin_set.register(plugin_with(Unweighted, hook="ssga_register_descriptors"), "unweighted")
    registry = ssga_plugin_set.registry()
    exp = validate_experiment(
        {
            "workspace": {"name": "test-wall"},
            "stages": STAGES,
            "variants": ["PD", {"variant": "D", "descriptor": {"name": "test-unweighted", "weights": "absent.pt"}}],
            "fuser": {"name": "rrf"},
            "training": {"epochs": 2, "hidden": 16},
        },
        registry,
    )
    report, _ = run_experiment(exp, dataset, tmp_path / "run")
    assert report.variants == ["PC-ST (PD)"]
    assert list(report.not_run) == ["UW (D)"] and "'weights' = 'absent.pt'" in report.not_run["UW (D)"]
    markdown = report.markdown()
    assert "| UW (D) ⚠ | not run |" in markdown and "- UW (D): not run, no weights:" in markdown
    assert "UW (D),not run" in report.csv()
