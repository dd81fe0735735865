"""The API speaks as the CLI does: a path the file system refuses (too long, through a file,
not permitted) is an InputError at the API whose message is the line the CLI prints.

Each test makes the path itself (a config field longer than the system allows, an output
folder under a file, a config file it may not read) and checks the API's error against the
CLI's line, without a traceback, with the user's files intact.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import cv2
import pytest
from pydantic import Field
from typer.testing import CliRunner

from ssga_bench.config import load_experiment
from ssga_bench.dataset_build import build_dataset
from ssga_bench.health import check_dataset
from ssga_bench.io import PathError, path_error, path_errors
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.testing import WallWorkspaceSource, cli_error_line, plugin_with, snapshot
from ssga_core.cli import app_with_plugin_commands
from ssga_core.config import resolve_stage
from ssga_core import plugins
from ssga_core.errors import InputError
from ssga_core.stages import StageConfig, WorkspaceSource
from ssga_core.testing import make_view

app = app_with_plugin_commands()
runner = CliRunner()
LONG = "a" * 300  # longer than a file name may be (255 on Linux and macOS)


class ScanConfig(StageConfig):
    path: Path = Field(description="The scan file.")


class ScanSource(WorkspaceSource):
    """A workspace source that checks its file as a mesh source does (``Path.is_file``)."""

    name = "test-scan"
    Config = ScanConfig

    @classmethod
    def missing(cls, config):
        return [] if config.path.is_file() else [f"path: no such file {config.path}"]

    def open(self):
        return WallWorkspaceSource().open()


@pytest.fixture
def workdir(tmp_path, monkeypatch, ssga_plugin_set):
    ssga_plugin_set.register(plugin_with(ScanSource, hook="ssga_register_workspaces"), "scan")
    from ssga_bench import testing as stand_in_workspaces
    from ssga_core.testing import stages as stand_in_stages

    ssga_plugin_set.load_entry_points()
    ssga_plugin_set.register(stand_in_stages, "stand-ins")
    ssga_plugin_set.register(stand_in_workspaces, "stand-in-workspaces")
    registry = ssga_plugin_set.registry()
    monkeypatch.setattr("ssga_core.plugins.default_registry", lambda: registry)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("mine")
    view = make_view(seed=1)
    cv2.imwrite(str(tmp_path / "img.png"), cv2.cvtColor(view.rgb, cv2.COLOR_RGB2BGR))
    return tmp_path


def cli_line(*args) -> str:
    return cli_error_line(runner.invoke(app, [str(a) for a in args])).removeprefix("error: ")


def api_message(call) -> str:
    with pytest.raises(InputError) as info:
        call()
    message = str(info.value)
    assert "\n" not in message, message
    return message


def config(text: str) -> Path:
    path = Path("exp.toml")
    path.write_text('variants = ["PD"]\n[stages]\nparser = { name = "test-stripes" }\ndescriptor = { name = "test-patch-colour" }\n' + text)
    return path


def test_a_config_path_field_longer_than_the_system_allows(workdir):
    path = config(f'[workspace]\nname = "test-scan"\npath = "{LONG}.ply"\n')
    before = snapshot(workdir)
    message = api_message(lambda: load_experiment(path, plugins.default_registry()))
    assert message == f"{LONG}.ply: File name too long"  # relative to the config's folder, as written
    assert cli_line("config", "validate", path) == message
    assert cli_line("run", path) == message
    assert snapshot(workdir) == before


def test_a_config_file_name_longer_than_the_system_allows(workdir):
    message = api_message(lambda: load_experiment(f"{LONG}.toml", plugins.default_registry()))
    assert message == f"{LONG}.toml: File name too long"
    assert cli_line("run", f"{LONG}.toml") == message


@pytest.mark.parametrize(("out", "why"), [(LONG, "File name too long"), ("afile/sub", "Not a directory")])
def test_output_paths_the_system_refuses(workdir, out, why):
    before = snapshot(workdir)
    registry = plugins.default_registry()
    wall = WallWorkspaceSource().open()
    small = ProtocolConfig(cells=2, test_per_class=1)
    calls = {
        ("workspace", "build", "--source", "test-wall", "--cells", "2", "--test-per-class", "1", "--out", out): lambda: build_dataset(
            wall, out, source={"name": "test-wall"}, protocol=small
        ),
        ("workspace", "verify", out): lambda: check_dataset(out) if not check_dataset(out).healthy else None,
    }
    from ssga_bench.extract import extract_features
    from ssga_bench.parse import parse_images
    from ssga_bench.synthesize import synthesize_image

    descriptor = resolve_stage("descriptor", {"name": "test-patch-colour"}, registry)
    parser = resolve_stage("parser", {"name": "test-stripes"}, registry)
    shift = resolve_stage("synthesizer", {"name": "test-shift"}, registry)
    calls[("extract", "img.png", "--descriptor", "test-patch-colour", "--out", f"{out}/f.h5")] = lambda: extract_features(["img.png"], descriptor, f"{out}/f.h5")
    calls[("parse", "img.png", "--parser", "test-stripes", "--out", out)] = lambda: parse_images(["img.png"], parser, out)
    # Said before the synthesis (test-shift, without the depth it needs, would fail after it).
    calls[("synthesize", "img.png", "--synthesizer", "test-shift", "--move", "0.5,0,0", "--out", out)] = lambda: synthesize_image(
        shift.create(), "img.png", (0.5, 0.0, 0.0), out
    )
    for args, call in calls.items():
        if args[1] == "verify":
            message = api_message(lambda: check_dataset(out))
        else:
            message = api_message(call)
        assert why in message and "Errno" not in message and message.startswith(out.split("/")[0]), (args, message)
        assert cli_line(*args) == message, args
    assert snapshot(workdir) == before


def test_run_output_the_system_refuses(workdir):
    path = config('[workspace]\nname = "test-wall"\nsize = 8\n[protocol]\ncells = 2\ntest_per_class = 1\n')
    from ssga_bench.experiment import run

    experiment = load_experiment(path, plugins.default_registry())
    for out, why in [(LONG, "File name too long"), ("afile/sub", "Not a directory")]:
        message = api_message(lambda: run(experiment=experiment, output=Path(out)))
        assert why in message
        assert cli_line("run", path, "--output", out) == message
    assert not (workdir / "runs").exists()


def test_a_config_it_may_not_read(workdir, monkeypatch):
    path = config('[workspace]\nname = "test-wall"\n')
    real = Path.read_text

    def refused(self, *args, **kwargs):
        if self.name == "exp.toml":
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "read_text", refused)
    message = api_message(lambda: load_experiment(path, plugins.default_registry()))
    assert "Permission denied" in message and str(path) in message
    assert cli_line("run", path) == message


def test_a_workspace_it_may_not_open(workdir, monkeypatch):
    """An OSError inside a library function (here a workspace's files) is a PathError with the CLI's line."""

    def denied(self):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), "/scans/home.ply")

    monkeypatch.setattr(ScanSource, "open", denied)
    monkeypatch.setattr(ScanSource, "missing", classmethod(lambda cls, config: []))
    stage = resolve_stage("workspace", {"name": "test-scan", "path": "home.ply"}, plugins.default_registry())
    from ssga_bench.dataset_build import build_workspace

    message = api_message(lambda: build_workspace(stage, ProtocolConfig(cells=2, test_per_class=1), out=Path("ws")))
    assert message == "/scans/home.ply: Permission denied"
    assert cli_line("workspace", "build", "--source", "test-scan", "-o", "path=home.ply", "--out", "ws") == message
    assert not Path("ws").exists()


def test_path_error_is_an_input_error_and_an_os_error():
    error = path_error(OSError(errno.ENAMETOOLONG, os.strerror(errno.ENAMETOOLONG), "x" * 10))
    assert isinstance(error, InputError) and isinstance(error, OSError) and isinstance(error, PathError)
    assert str(error) == f"{'x' * 10}: File name too long" and error.errno == errno.ENAMETOOLONG and error.filename == "x" * 10
    with pytest.raises(PathError, match="^Not a directory$"), path_errors():
        raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR))
