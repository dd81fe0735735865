"""Workspaces that heal: every file of a built dataset is checked against what the folder records
and re-made from the workspace, bit for bit, by ``ssga workspace build`` over it and before
``ssga run`` starts; ``ssga workspace verify`` reports a dataset's health without changing it.

Each test makes the accident itself (a deleted view, a truncated PNG, a zero-byte file, a flipped
bit, a damaged record) on the stand-in wall workspace, and checks the user's files stay as they
were and that either the dataset healed or one line says what is wrong and how to heal it.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

import ssga_bench.io
from ssga_bench.dataset import Dataset
from ssga_bench.dataset_build import build_dataset
from ssga_bench.health import check_dataset
from ssga_bench.io import png_problem
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.testing import WallWorkspaceSource, cli_error_line, read_only_below, snapshot
from ssga_core.cli import app_with_plugin_commands
from ssga_core.errors import InputError

app = app_with_plugin_commands()
runner = CliRunner()

SMALL = ProtocolConfig(cells=2, test_per_class=1, seed=4)
BUILD = ["workspace", "build", "--source", "test-wall", "--option", "size=8", "--cells", "2", "--test-per-class", "1", "--executor", "serial"]


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def one_line_error(result, *names) -> str:
    return cli_error_line(result, *names, passing=("warning: ",))


def build(out, **kw):
    return build_dataset(WallWorkspaceSource().open(), out, source={"name": "test-wall"}, protocol=SMALL, **kw)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A finished dataset and its files as first written."""
    out = tmp_path_factory.mktemp("built") / "ds"
    build(out)
    return out, snapshot(out)


@pytest.fixture
def dataset(built, tmp_path):
    """A fresh copy of the built dataset to damage."""
    source, files = built
    out = tmp_path / "ds"
    for name, data in files.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(data)
    return out, files


def damage(out: Path) -> dict[str, str]:
    """The accidents: a deleted view, a truncated PNG, a zero-byte depth map, a record emptied; what each is."""
    rows = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    test = [r["id"] for r in rows if r["split"] == "test"]
    (out / "rgb" / f"{test[0]}.png").unlink()
    data = (out / "rgb" / f"{test[1]}.png").read_bytes()
    (out / "rgb" / f"{test[1]}.png").write_bytes(data[: len(data) // 2])
    (out / "depth" / f"{test[2]}.png").write_bytes(b"")
    (out / "semantic" / f"{test[3]}.png").unlink()
    return {
        f"rgb/{test[0]}.png": "missing",
        f"rgb/{test[1]}.png": "truncated",
        f"depth/{test[2]}.png": "empty (0 bytes)",
        f"semantic/{test[3]}.png": "missing",
    }


# --- checking: cheap, and without changing anything ---


def test_a_healthy_dataset_checks_healthy(dataset):
    out, files = dataset
    health = check_dataset(out)
    assert health.healthy and health.damaged == {}
    assert health.views == len(Dataset.open(out).plan.samples)
    assert health.files == 4 + 4 * health.views  # dataset, floorplan, plan and manifest; four channels per view
    assert check_dataset(out, decode=True).healthy
    assert snapshot(out) == files


def test_verify_names_each_damaged_file_and_changes_nothing(dataset, stand_ins):
    out, _ = dataset
    made = damage(out)
    before = snapshot(out)
    result = invoke("workspace", "verify", out)
    line = one_line_error(result, out, "4 damaged or missing files", "ssga workspace build --config CONFIG --out")
    for path, why in made.items():
        assert re.search(rf"^{re.escape(str(out / path))}: {re.escape(why)}", result.stdout, re.M), (path, result.stdout)
    assert "rgb/" in line and snapshot(out) == before
    result = invoke("workspace", "verify", out, "--decode")
    assert result.exit_code == 1 and snapshot(out) == before


def test_verify_says_an_unfinished_build_and_a_folder_that_is_no_dataset(dataset, tmp_path, stand_ins):
    out, _ = dataset
    (out / "manifest.jsonl").unlink()
    line = one_line_error(invoke("workspace", "verify", out), "the build did not finish", f"--out {out}` resumes it")
    assert "damaged" not in line
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.jpg").write_bytes(b"jpeg")
    one_line_error(invoke("workspace", "verify", tmp_path / "photos"), "not an ssga dataset (no dataset.json)")
    one_line_error(invoke("workspace", "verify", tmp_path / "nothing"), "no such folder")


@pytest.mark.parametrize(
    ("accident", "why"),
    [
        (lambda p: p.write_bytes(p.read_bytes()[:-12]), "truncated"),  # its IEND chunk cut off
        (lambda p: p.write_bytes(p.read_bytes()[:20]), "not a PNG"),
        (lambda p: p.write_bytes(b"\x89PNG\r\n\x1a\n" + b"x" * 100), "not a PNG"),
        (lambda p: p.write_bytes(b""), "empty (0 bytes)"),
        (lambda p: p.unlink(), "missing"),
    ],
)
def test_each_accident_to_a_png_is_found_cheaply(dataset, accident, why):
    out, _ = dataset
    path = sorted((out / "instance").iterdir())[0]
    accident(path)
    health = check_dataset(out)
    assert list(health.damaged) == [f"instance/{path.name}"] and health.damaged[f"instance/{path.name}"].startswith(why)


def test_a_png_of_another_size_or_kind_is_found(dataset):
    out, _ = dataset
    rgb, depth = sorted((out / "rgb").iterdir())[0], sorted((out / "depth").iterdir())[0]
    other = sorted((out / "rgb").iterdir())[1].read_bytes()
    depth.write_bytes(other)  # an 8-bit colour image where 16-bit millimetres belong
    assert "expected bit depth 16" in check_dataset(out).damaged[f"depth/{depth.name}"]
    import cv2
    import numpy as np

    rgb.write_bytes(cv2.imencode(".png", np.zeros((5, 7, 3), np.uint8))[1].tobytes())
    assert check_dataset(out).damaged[f"rgb/{rgb.name}"].startswith("a 7 x 5 image, expected")


def test_a_flipped_bit_is_found_when_decoding(dataset):
    out, _ = dataset
    path = sorted((out / "rgb").iterdir())[0]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x40
    path.write_bytes(bytes(data))
    assert check_dataset(out).healthy  # sizes, headers and ends are as written
    assert "fails its CRC" in check_dataset(out, decode=True).damaged[f"rgb/{path.name}"]
    assert png_problem(path, decode=True) is not None


# --- healing: bit for bit, and said ---


def test_build_over_a_damaged_dataset_re_makes_it_bit_for_bit(dataset, stand_ins, capsys):
    out, files = dataset
    made = damage(out)
    (out / "notes.txt").write_text("mine")
    ds = build(out)
    assert sorted(ds.remade) == sorted(made)
    assert f"warning: {out}: re-made its 4 damaged or missing files" in capsys.readouterr().err
    assert snapshot(out) == {**files, "notes.txt": b"mine"}
    assert check_dataset(out).healthy
    assert build(out).remade == ()  # healthy now: nothing more to do


def test_workspace_build_says_how_many_it_re_made(tmp_path, stand_ins):
    out = tmp_path / "ws"
    assert invoke(*BUILD, "--out", out).exit_code == 0
    files = snapshot(out)
    made = damage(out)
    result = invoke(*BUILD, "--out", out)
    assert result.exit_code == 0, result.output
    assert result.stdout.strip().endswith(f"re-made {len(made)} damaged or missing files")
    assert snapshot(out) == files
    # A flipped bit inside a file needs --decode to be seen.
    path = out / next(iter(made))
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x40
    path.write_bytes(bytes(data))
    assert "re-made" not in invoke(*BUILD, "--out", out).stdout
    result = invoke(*BUILD, "--out", out, "--decode")
    assert result.exit_code == 0 and result.stdout.strip().endswith("re-made 1 damaged or missing file")
    assert snapshot(out) == files


@pytest.mark.parametrize("record", ["dataset.json", "plan.json", "manifest.jsonl", "floorplan.json"])
@pytest.mark.parametrize("accident", ["delete", "empty", "garble"])
def test_each_record_is_re_made(dataset, record, accident):
    out, files = dataset
    path = out / record
    if accident == "delete":
        path.unlink()
    elif accident == "empty":
        path.write_bytes(b"")
    else:
        path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 3])
    assert not check_dataset(out).healthy
    ds = build(out)
    # Without its manifest a dataset is an unfinished build (the manifest is written last): finished, not healed.
    assert ds.remade == ((record,) if (record, accident) != ("manifest.jsonl", "delete") else ())
    assert snapshot(out) == files


def test_a_damaged_header_is_healed_only_where_the_plan_is_this_builds(dataset):
    out, _ = dataset
    (out / "dataset.json").write_bytes(b"")
    (out / "notes.txt").write_text("mine")
    before = snapshot(out)
    other = ProtocolConfig(cells=2, test_per_class=1, seed=5)
    with pytest.raises(InputError, match=r"dataset\.json: empty \(0 bytes\), and its plan\.json is not the one these settings give") as info:
        build_dataset(WallWorkspaceSource().open(), out, source={"name": "test-wall"}, protocol=other, overwrite=True)
    assert "\n" not in str(info.value) and "nothing was changed" in str(info.value)
    assert snapshot(out) == before
    (out / "plan.json").unlink()
    with pytest.raises(InputError, match="no plan.json shows which dataset ssga wrote here"):
        build(out)


def test_a_dataset_in_a_read_only_folder_says_what_and_how(dataset, stand_ins, monkeypatch):
    out, _ = dataset
    made = damage(out)
    before = snapshot(out)
    read_only = read_only_below(out, ssga_bench.io.atomic_write_bytes)
    monkeypatch.setattr("ssga_bench.io.atomic_write_bytes", read_only)
    monkeypatch.setattr("ssga_bench.dataset_build.atomic_write_bytes", read_only)
    with pytest.raises(InputError) as info:
        build(out)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{out}: cannot re-make its 4 damaged or missing files: ")
    assert next(iter(made)) in message and "Read-only file system" in message
    assert f"ssga workspace build --config CONFIG --out {out}" in message
    assert snapshot(out) == before


def test_a_damaged_view_read_by_a_run_names_the_command_that_heals_it(dataset):
    out, _ = dataset
    ds = Dataset.open(out)
    sample = ds.split("test")[0]
    (out / "rgb" / f"{sample.id}.png").write_bytes(b"")
    with pytest.raises(InputError, match=rf"rgb/{sample.id}.png: not a readable image; `ssga workspace verify {re.escape(str(out))}` lists"):
        ds.view(sample)


def test_run_heals_its_workspace_before_it_starts(tmp_path, stand_ins, monkeypatch):
    """``ssga run`` builds (or reuses) its workspace through build_workspace: a damaged one is healed there."""
    monkeypatch.chdir(tmp_path)
    config = tmp_path / "exp.toml"
    config.write_text(
        '\n'.join(
            [
                'variants = ["PD"]',
                "[workspace]",
                'name = "test-wall"',
                "size = 8",
                "[protocol]",
                "cells = 2",
                "test_per_class = 1",
                "[stages]",
                'parser = { name = "test-stripes" }',
                'descriptor = { name = "test-patch-colour" }',
                "[execution]",
                'executor = "serial"',
            ]
        )
    )
    assert invoke("workspace", "build", "--config", config).exit_code == 0
    (folder,) = (tmp_path / "runs" / "workspaces").iterdir()
    files = snapshot(folder)
    made = damage(folder)
    result = invoke("run", config, "--output", "out")
    assert result.exit_code == 0, result.output
    assert f"warning: {folder.relative_to(tmp_path)}: re-made its {len(made)} damaged or missing files" in result.stderr
    assert snapshot(folder) == files
    assert (tmp_path / "out" / "report.md").exists()


class Captured:
    """A captured workspace (a grid of poses, each a capture of the wall room), counting loads."""

    def __init__(self) -> None:
        import math

        import numpy as np

        from ssga_core.geometry import Pose

        inner = WallWorkspaceSource().open()
        self.inner, self.name, self.camera, self.floor_plan = inner, "test-captured", inner.camera, inner.floor_plan
        grid = np.arange(-4, 4.1, 0.5)
        self.captures = [Pose(float(x), float(y), math.radians(12 * k), 1.5) for x in grid for y in grid for k in range(30)]
        self.loads = 0

    def load(self, index):
        self.loads += 1
        return self.inner.render(self.captures[index])


def test_a_captured_workspace_heals_from_its_captures(tmp_path):
    out = tmp_path / "ds"
    ds = build_dataset(Captured(), out, source={"name": "test-captured"}, protocol=SMALL)
    files = snapshot(out)
    assert ds.split("target") and not (out / "rgb" / f"{ds.split('target')[0].id}.png").exists()  # targets have no image
    assert check_dataset(out).healthy
    made = damage(out)
    workspace = Captured()
    again = build_dataset(workspace, out, source={"name": "test-captured"}, protocol=SMALL)
    assert sorted(again.remade) == sorted(made) and workspace.loads == len(made)  # a view loaded once per damaged file here
    assert snapshot(out) == files


@pytest.mark.parametrize("accident", ["delete", "garble"])
def test_the_fitted_values_are_re_made(tmp_path, accident, capsys):
    fitted = ProtocolConfig(cells=2, cell_size=30.0, test_per_class=2, seed=4)  # 30 m cells in a 10 m room: fitted to 3 m
    out = tmp_path / "ds"
    build_dataset(WallWorkspaceSource().open(), out, source={"name": "test-wall"}, protocol=fitted, fit=True)
    files = snapshot(out)
    assert "fitted.json" in files
    if accident == "delete":
        (out / "fitted.json").unlink()
    else:
        (out / "fitted.json").write_text("{")
    assert list(check_dataset(out).damaged) == ["fitted.json"]
    ds = build_dataset(WallWorkspaceSource().open(), out, source={"name": "test-wall"}, protocol=fitted, fit=True)
    assert ds.remade == ("fitted.json",) and ds.plan.config.cell_size == 3.0
    assert snapshot(out) == files
