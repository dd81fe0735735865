"""Every learned plugin, given a bad ``weights`` file, says so in one line and runs nothing from it.

What users download or copy goes wrong in a few ways: a transfer cut short, a file that is
not a checkpoint at all, another network's checkpoint, and a pickle that would run code
when loaded. For each, making the stage raises an ssga error (the command line prints it
as one line, exit 1, no traceback) naming the ``weights`` field and the file, and the
malicious pickle's code never runs (``torch.load(weights_only=True)``).
"""

from __future__ import annotations

import os
import shlex

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from ssga_bench import checkpoint_bytes, write_png
from ssga_bench.testing import RunsCode
from ssga_core import SsgaError, resolve_stage
from ssga_core.cli import app_with_plugin_commands

LEARNED = [("descriptor", "pnv"), ("descriptor", "cnn-rrf"), ("descriptor", "depth-layout"), ("parser", "cascade-seg"), ("parser", "detic"), ("synthesizer", "midas-warp"), ("synthesizer", "synsin")]


def bad_file(kind: str, folder) -> str:
    path = folder / f"{kind}.pt"
    whole = checkpoint_bytes({"state_dict": {"fc.weight": torch.zeros(10, 5), "fc.bias": torch.zeros(10)}})
    if kind == "truncated":
        path.write_bytes(whole[: len(whole) // 2])
    elif kind == "random-bytes":
        path.write_bytes(os.urandom(4096))
    elif kind == "wrong-model":
        path.write_bytes(whole)  # a readable checkpoint of another network
    elif kind == "malicious":
        torch.save({"state_dict": RunsCode(f"touch {shlex.quote(str(folder / 'ran'))}")}, path)
    return str(path)


@pytest.mark.parametrize("kind", ["truncated", "random-bytes", "wrong-model", "malicious"])
@pytest.mark.parametrize(("stage_kind", "name"), LEARNED)
def test_a_bad_weights_file_is_one_line_and_runs_nothing(ssga_installed_registry, tmp_path, stage_kind, name, kind):
    path = bad_file(kind, tmp_path)
    options = {"name": name, "weights": path, "device": "cpu"}
    if name == "detic":  # its vocabulary is checked first: give it one, so that the weights are what is wrong
        np.save(tmp_path / "vocabulary.npy", np.random.default_rng(0).normal(size=(3, 512)).astype(np.float16))
        (tmp_path / "names.txt").write_text("chair\ntable\nlamp\n")
        options |= {"vocabulary": str(tmp_path / "vocabulary.npy"), "class_names": str(tmp_path / "names.txt")}
    with pytest.raises(SsgaError) as err:
        resolve_stage(stage_kind, options, ssga_installed_registry).create()
    message = str(err.value)
    assert "\n" not in message and "'weights'" in message and f"{kind}.pt" in message, message
    assert not (tmp_path / "ran").exists()


def test_the_malicious_file_is_live(tmp_path):
    """Loaded unsafely, it runs: the tests above would catch a loader that did so."""
    torch.load(bad_file("malicious", tmp_path), weights_only=False)
    assert (tmp_path / "ran").exists()


def test_the_command_line_says_it_in_one_line_without_a_traceback(tmp_path):
    image = tmp_path / "view.png"
    write_png(image, torch.zeros(64, 64, 3, dtype=torch.uint8).numpy())
    weights = bad_file("malicious", tmp_path)
    result = CliRunner().invoke(
        app_with_plugin_commands(), ["synthesize", str(image), "--synthesizer", "midas-warp", "--move", "0.5,0,10", "-o", f"weights={weights}", "--out", str(tmp_path / "out")]
    )
    assert result.exit_code == 1 and "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "malicious.pt" in errors[0]
    assert not (tmp_path / "ran").exists()
