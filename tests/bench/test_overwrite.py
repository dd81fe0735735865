"""ssga replaces only what it wrote: every command that writes into a folder or file the user
names knows its own files again by a marker, and refuses, with one line and nothing changed,
to replace anything else (``--overwrite`` included).

Each test puts the user's own files where ssga would write (a foreign ``dataset.json``, a
``report.md``, an ``index.html``, a ``synthetic.png``, an HDF5 file), checks the refusal is one
line at the CLI and the same message as an InputError at the API, and that every file is intact.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from ssga_bench.dataset_build import build_dataset
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.testing import WallWorkspaceSource, cli_error_line, snapshot
from ssga_core.cli import app_with_plugin_commands
from ssga_core.errors import InputError
from ssga_core.testing import make_view

app = app_with_plugin_commands()
runner = CliRunner()

BUILD = ["workspace", "build", "--source", "test-wall", "--option", "size=8", "--cells", "2", "--test-per-class", "1", "--executor", "serial"]
CONFIG = """
variants = ["PD"]
[workspace]
name = "test-wall"
size = 8
[protocol]
cells = 2
test_per_class = 1
[stages]
parser = { name = "test-stripes" }
descriptor = { name = "test-patch-colour" }
[training]
epochs = 2
hidden = 16
[execution]
executor = "serial"
"""


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def refused(result, *names) -> str:
    """The one ``error:`` line of a refusal, without a traceback, naming each of ``names``; the message without ``error: ``."""
    line = cli_error_line(result, *names)
    assert "nothing was changed" in line
    return line.removeprefix("error: ")


def refused_unchanged(root: Path, args, *names) -> str:
    """``ssga *args`` refused (:func:`refused`), every file below ``root`` as it was; the message."""
    before = snapshot(root)
    message = refused(invoke(*args), *names)
    assert snapshot(root) == before
    return message


@pytest.fixture
def workdir(tmp_path, monkeypatch, stand_ins):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "exp.toml").write_text(CONFIG)
    return tmp_path


# --- workspace build ---


@pytest.mark.parametrize("header", ['{"name": "my data", "files": 3}', "[1, 2]"])
@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_a_users_own_dataset_json_is_never_replaced(workdir, header, overwrite):
    out = workdir / "mine"
    out.mkdir()
    (out / "dataset.json").write_text(header)
    (out / "notes.txt").write_text("notes")
    before = snapshot(workdir)
    message = refused(invoke(*BUILD, "--out", out, *overwrite), out / "dataset.json", "not written by ssga")
    assert snapshot(workdir) == before
    with pytest.raises(InputError) as info:
        build_dataset(WallWorkspaceSource().open(), out, source={"name": "test-wall"}, protocol=ProtocolConfig(cells=2, test_per_class=1), overwrite=bool(overwrite))
    assert str(info.value).startswith(message.split(" (")[0]) and "\n" not in str(info.value)
    assert snapshot(workdir) == before


def test_overwrite_on_a_folder_ssga_did_not_write_is_refused(workdir):
    out = workdir / "photos"
    out.mkdir()
    (out / "holiday.jpg").write_bytes(b"jpeg")
    refused_unchanged(workdir, [*BUILD, "--out", out, "--overwrite"], out, "not a dataset folder ssga wrote", "--overwrite")
    # Without --overwrite, a new dataset may share a folder with the user's files: nothing of theirs is replaced.
    assert invoke(*BUILD, "--out", out).exit_code == 0
    assert (out / "holiday.jpg").read_bytes() == b"jpeg"
    # An empty folder is no one's: --overwrite builds there.
    (workdir / "empty").mkdir()
    assert invoke(*BUILD, "--out", workdir / "empty", "--overwrite").exit_code == 0


def test_a_new_build_never_replaces_a_users_file_where_a_view_goes(workdir):
    out = workdir / "ws"
    assert invoke(*BUILD, "--out", out).exit_code == 0
    view = sorted((out / "rgb").iterdir())[3].name
    target = workdir / "mine"
    (target / "rgb").mkdir(parents=True)
    (target / "rgb" / view).write_bytes(b"my picture")
    refused_unchanged(workdir, [*BUILD, "--out", target], target / "rgb" / view, "not written by ssga")


def test_overwrite_replaces_a_dataset_ssga_wrote(workdir):
    out = workdir / "ws"
    assert invoke(*BUILD, "--out", out).exit_code == 0
    (out / "notes.txt").write_text("mine")
    assert invoke(*BUILD, "--out", out, "--seed", "7").exit_code == 1  # other settings: refused without --overwrite
    assert invoke(*BUILD, "--out", out, "--seed", "7", "--overwrite").exit_code == 0
    assert json.loads((out / "dataset.json").read_text())["protocol"]["seed"] == 7
    assert (out / "notes.txt").read_text() == "mine"


# --- run and bench ---


@pytest.mark.parametrize("name", ["report.md", "index.html", "results.csv"])
def test_run_never_replaces_a_users_file_in_its_output(workdir, stand_ins, name):
    out = workdir / "out"
    out.mkdir()
    (out / name).write_text("mine")
    before = snapshot(workdir)
    message = refused(invoke("run", "exp.toml", "--output", out), out / name, "not written by ssga run", "--output")
    assert snapshot(workdir) == before
    assert not (workdir / "runs").exists()  # refused before the workspace was built
    from ssga_bench.config import load_experiment
    from ssga_bench.experiment import run

    with pytest.raises(InputError) as info:
        run(experiment=load_experiment("exp.toml", stand_ins), output=out)
    assert str(info.value) == message
    assert snapshot(workdir) == before


def test_a_run_folder_is_marked_and_run_again(workdir):
    out = workdir / "out"
    assert invoke("run", "exp.toml", "--output", out).exit_code == 0
    assert json.loads((out / "run.json").read_text()) == {"format": 1, "written_by": "ssga run"}
    assert invoke("run", "exp.toml", "--output", out).exit_code == 0  # its own files: replaced
    # A run folder written before runs were marked is known by its trained variants, and marked.
    (out / "run.json").unlink()
    assert invoke("run", "exp.toml", "--output", out).exit_code == 0
    assert (out / "run.json").exists()


def test_run_refuses_a_marker_it_did_not_write(workdir):
    out = workdir / "out"
    out.mkdir()
    (out / "run.json").write_text('{"my": "run"}')
    refused_unchanged(workdir, ["run", "exp.toml", "--output", out], out / "run.json", "not written by ssga run")


def test_bench_never_replaces_a_users_file_in_its_output(workdir, monkeypatch):
    monkeypatch.setattr("ssga_bench.bench.run", lambda **kw: pytest.fail("ran a seed"))
    out = workdir / "out"
    out.mkdir()
    (out / "index.html").write_text("<p>mine</p>")
    refused_unchanged(workdir, ["bench", "exp.toml", "--seeds", "0", "--output", out], out / "index.html", "not written by ssga bench")


# --- extract, parse, synthesize ---


@pytest.fixture
def image(workdir):
    path, view = workdir / "img.png", make_view(seed=1)
    cv2.imwrite(str(path), cv2.cvtColor(view.rgb, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(workdir / "img-depth.png"), np.rint(view.depth * 1000).astype(np.uint16))
    return path


def synthesize(image: Path, out: Path) -> list:
    """``ssga synthesize`` of the ``image`` fixture (its depth beside it) into ``out``."""
    return ["synthesize", image, "--depth", image.parent / "img-depth.png", "--synthesizer", "test-shift", "--move", "0.5,0,0", "--out", out]


@pytest.mark.parametrize("kind", ["text", "hdf5"])
def test_extract_never_replaces_a_users_file(workdir, image, kind):
    out = workdir / "features.h5"
    if kind == "text":
        out.write_text("my notes")
    else:
        with h5py.File(out, "w") as h5:
            h5.create_dataset("mine", data=np.arange(3))
    refused_unchanged(workdir, ["extract", image, "--descriptor", "test-patch-colour", "--out", out], out, "not written by ssga extract")


def test_extract_replaces_its_own_file(workdir, image):
    out = workdir / "features.h5"
    assert invoke("extract", image, "--descriptor", "test-patch-colour", "--out", out).exit_code == 0
    assert invoke("extract", image, "--descriptor", "test-patch-colour", "--out", out).exit_code == 0


@pytest.mark.parametrize(("name", "data"), [("img.graph.png", b"my drawing"), ("img.labels.png", b"my labels"), ("img.regions.json", b'{"regions": []}')])
def test_parse_never_replaces_a_users_file(workdir, image, name, data):
    out = workdir / "graphs"
    out.mkdir()
    (out / name).write_bytes(data)
    refused_unchanged(workdir, ["parse", image, "--parser", "test-stripes", "--out", out], out / name, "not written by ssga parse")


def test_parse_replaces_its_own_files(workdir, image):
    out = workdir / "graphs"
    assert invoke("parse", image, "--parser", "test-stripes", "--out", out).exit_code == 0
    first = snapshot(out)
    assert invoke("parse", image, "--parser", "test-stripes", "--out", out).exit_code == 0
    assert snapshot(out) == first


@pytest.mark.parametrize(("name", "data"), [("synthetic.png", b"my picture"), ("side-by-side.png", b"mine"), ("synthesis.json", b'{"mine": 1}')])
def test_synthesize_never_replaces_a_users_file(workdir, image, name, data):
    out = workdir / "syn"
    out.mkdir()
    (out / name).write_bytes(data)
    refused_unchanged(workdir, synthesize(image, out), out / name, "not written by ssga synthesize")


def test_synthesize_marks_its_folder_and_replaces_its_own_files(workdir, image):
    out = workdir / "syn"
    args = synthesize(image, out)
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    assert json.loads((out / "synthesis.json").read_text())["written_by"] == "ssga synthesize"
    assert invoke(*args).exit_code == 0


def test_bench_refuses_a_seed_folder_it_did_not_write_before_writing_anything(workdir, monkeypatch):
    monkeypatch.setattr("ssga_bench.bench.run", lambda **kw: pytest.fail("ran a seed"))
    out = workdir / "out"
    (out / "seed-1").mkdir(parents=True)
    (out / "seed-1" / "report.md").write_text("my report")
    refused_unchanged(workdir, ["bench", "exp.toml", "--seeds", "0,1", "--output", out], out / "seed-1" / "report.md", "not written by ssga run")
