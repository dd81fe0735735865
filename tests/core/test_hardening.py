"""The core against bad input: variant strings, and plugin modules that misbehave or are shadowed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ssga_core.cli import app_with_plugin_commands
from ssga_core.plugins import get_plugin_manager

SSGA = Path(sys.executable).with_name("ssga")
"""The venv's console script, by absolute path (the subprocesses run in a temporary folder)."""

app = app_with_plugin_commands()
runner = CliRunner()

VALID_PLUGIN = """
import numpy as np
import torch  # after plugin loading starts: the installed torch, not a torch.py beside this module

from ssga_core import Parser, Regions, hookimpl

assert hasattr(torch, "tensor")


class MyParser(Parser):
    name = "my-parser"

    def _parse(self, view):
        return Regions.from_labels(np.zeros(view.camera.shape, np.int32))


@hookimpl
def ssga_register_parsers():
    return [MyParser]
"""

STRAY = 'raise RuntimeError("stray {name}.py in the working directory was imported")\n'


def ssga(cwd: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """Run the installed ``ssga`` in ``cwd`` with only the ``SSGA_*`` variables given."""
    environ = {k: v for k, v in os.environ.items() if not k.startswith("SSGA_")}
    assert SSGA.exists(), SSGA
    return subprocess.run([str(SSGA), *args], cwd=cwd, env={**environ, **env}, capture_output=True, text=True, timeout=60)


def assert_clean(proc: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr
    assert "stray" not in proc.stderr + proc.stdout, proc.stderr


# --- 2. Module import safety: nothing in the working directory shadows an installed module ---


@pytest.fixture
def stray_modules(tmp_path):
    """A working directory with a torch.py and a numpy.py that fail loudly if imported."""
    for name in ("torch", "numpy"):
        (tmp_path / f"{name}.py").write_text(STRAY.format(name=name))
    return tmp_path


@pytest.mark.parametrize("args", [("variants", "--list"), ("plugins",)])
def test_stray_modules_in_the_working_directory_are_not_imported(stray_modules, args):
    proc = ssga(stray_modules, *args)
    assert proc.returncode == 0, proc.stderr
    assert_clean(proc)
    assert "ssga plugins" in proc.stdout or "variant orders" in proc.stdout


def test_a_plugin_module_in_the_working_directory_is_found_without_shadowing_installed_ones(stray_modules):
    (stray_modules / "my_plugin.py").write_text(VALID_PLUGIN)
    proc = ssga(stray_modules, "plugins", "--json", SSGA_PLUGIN_MODULES="my_plugin", SSGA_STRICT_PLUGINS="1")
    assert proc.returncode == 0, proc.stderr
    assert_clean(proc)
    data = json.loads(proc.stdout)
    mine = [p for p in data["plugins"] if p["name"] == "my-parser"]
    assert len(mine) == 1 and mine[0]["distribution"] == "(SSGA_PLUGIN_MODULES)" and mine[0]["kind"] == "parser"
    assert data["failures"] == []


def test_naming_an_installed_plugins_module_again_does_not_register_it_twice(tmp_path):
    proc = ssga(tmp_path, "plugins", "--json", SSGA_PLUGIN_MODULES="ssga_parser_slico.plugin", SSGA_STRICT_PLUGINS="1")
    assert proc.returncode == 0, proc.stderr
    assert "registered twice" not in proc.stderr
    data = json.loads(proc.stdout)
    assert [p["distribution"] for p in data["plugins"] if p["name"] == "slico"] == ["ssga-parser-slico"]
    assert data["failures"] == []


# --- 3. A plugin module that calls sys.exit() is a failure naming it, not the end of ssga ---


def write_module(folder: Path, name: str, text: str) -> str:
    (folder / f"{name}.py").write_text(text)
    return name


def test_load_modules_records_a_module_that_exits(tmp_path, monkeypatch):
    monkeypatch.delenv("SSGA_PLUGIN_MODULES", raising=False)
    monkeypatch.syspath_prepend(str(tmp_path))  # also restores sys.path, which load_modules extends
    exiting = write_module(tmp_path, "ssga_test_exits_at_import", "import sys\nsys.exit(3)\n")
    good = write_module(tmp_path, "ssga_test_good_after_exit", VALID_PLUGIN)
    plugins = get_plugin_manager(load_entrypoints=False)
    plugins.load_modules([exiting, good])
    (failure,) = plugins.failures
    assert str(failure) == f"plugin {exiting!r} (SSGA_PLUGIN_MODULES) failed to load: importing {exiting} called sys.exit(3)"
    # The module after it still loads.
    assert plugins.registry().entry("parser", "my-parser").plugin.name == good


def test_get_plugin_manager_records_modules_that_exit_at_import_or_in_a_hook(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    at_import = write_module(tmp_path, "ssga_test_exits_too", "raise SystemExit('bye')\n")
    in_hook = write_module(
        tmp_path, "ssga_test_exits_in_hook", "import sys\nfrom ssga_core import hookimpl\n\n@hookimpl\ndef ssga_register_parsers():\n    sys.exit(4)\n"
    )
    monkeypatch.setenv("SSGA_PLUGIN_MODULES", f"{at_import},{in_hook}")
    registry = get_plugin_manager(load_entrypoints=False).registry()
    reasons = {f.plugin.name: f.reason for f in registry.failures}
    assert reasons == {at_import: f"importing {at_import} called sys.exit('bye')", in_hook: "ssga_register_parsers() raised SystemExit: 4"}


def test_the_cli_survives_a_plugin_module_that_exits(tmp_path):
    write_module(tmp_path, "exiting_plugin", "import sys\nsys.exit(3)\n")
    proc = ssga(tmp_path, "plugins", SSGA_PLUGIN_MODULES="exiting_plugin")
    assert proc.returncode == 0, proc.stderr
    assert "ssga plugins" in proc.stdout and "ssga-parser-grid" in proc.stdout
    reason = "plugin 'exiting_plugin' (SSGA_PLUGIN_MODULES) failed to load: importing exiting_plugin called sys.exit(3)"
    assert proc.stderr.strip() == f"warning: {reason}"

    strict = ssga(tmp_path, "plugins", SSGA_PLUGIN_MODULES="exiting_plugin", SSGA_STRICT_PLUGINS="1")
    assert strict.returncode == 1
    assert strict.stderr.strip() == f"error: {reason} (SSGA_STRICT_PLUGINS is set)"
    assert "Traceback" not in strict.stderr and "ssga plugins" not in strict.stdout


# --- 5. Variant grammar: a column for every error, in every command ---
# (The grammar's own cases, non-ASCII digits, bounded presets and long inputs, are in test_variants.py.)


def test_config_validate_reports_bad_variants_with_columns(tmp_path, monkeypatch, ssga_plugin_set):
    from ssga_bench import testing as stand_in_workspaces
    from ssga_core.testing import stages as stand_in_stages

    ssga_plugin_set.load_entry_points()
    ssga_plugin_set.register(stand_in_stages, "stand-ins")
    ssga_plugin_set.register(stand_in_workspaces, "stand-in-workspaces")
    registry = ssga_plugin_set.registry()
    monkeypatch.setattr("ssga_core.plugins.default_registry", lambda: registry)
    bad = ["PD²", "PD٣", "PD" + "9" * 5000, "PD1234567"]
    path = tmp_path / "exp.toml"
    path.write_text(
        f"variants = {json.dumps(['PD3', *bad], ensure_ascii=False)}\n"
        '[workspace]\nname = "test-wall"\n'
        '[stages]\nparser = { name = "test-stripes" }\ndescriptor = { name = "test-patch-colour" }\n',
        encoding="utf-8",
    )
    result = runner.invoke(app, ["config", "validate", str(path)])
    assert result.exit_code == 1
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    lines = result.stderr.splitlines()
    assert lines[0] == f"error: {path}: 4 problems"
    for n, (line, column) in enumerate(zip(lines[1:], (3, 3, 9, 9)), 1):
        assert line.strip().startswith(f"variants[{n}].variant: invalid variant "), line[:80]
        assert f"column {column}:" in line


# --- stage configs refuse non-finite numbers ------------------------------------------
def test_stage_configs_refuse_inf_and_nan(ssga_plugin_set):
    from ssga_bench import testing as stand_in_workspaces
    from ssga_core import ConfigError, resolve_stage

    ssga_plugin_set.register(stand_in_workspaces, "stand-in-workspaces")
    registry = ssga_plugin_set.registry()
    for value in (float("inf"), float("nan")):
        with pytest.raises(ConfigError, match=r"workspace\.size: Input should be a finite number"):
            resolve_stage("workspace", {"name": "test-wall", "size": value}, registry)
