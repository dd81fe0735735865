"""The execution layer: every executor maps a task the same way, and a run's results do not
depend on the executor or the number of workers, to the bit."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ssga_bench.execution import ExecutionConfig, ProcessExecutor, SerialExecutor, TaskCrashed, open_executor
from ssga_bench.testing import task_fails, task_square, task_thread_counts
from ssga_core.errors import InputError, SsgaError


@pytest.fixture(scope="module")
def local_ray():
    """A small local Ray of this module's own, shut down after (never `ray stop`: it ends every Ray on the machine)."""
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        pytest.skip("a Ray is already running in this process")
    ray.init(num_cpus=2, object_store_memory=100 * 1024**2, include_dashboard=False, logging_level="ERROR")
    yield ray
    ray.shutdown()


def executors(request_param, local_ray=None):
    if request_param == "serial":
        return SerialExecutor()
    if request_param.startswith("processes"):
        return ProcessExecutor(int(request_param.split("-")[1]))
    return open_executor(ExecutionConfig(executor="ray", workers=2))


@pytest.mark.parametrize("kind", ["serial", "processes-2"])
def test_results_come_back_in_job_order_with_progress(kind):
    seen = []
    with executors(kind) as executor:
        out = list(executor.map(task_square, range(11), progress=lambda done, total: seen.append((done, total))))
    assert out == [x * x for x in range(11)]
    assert [d for d, _ in seen] == list(range(1, 12)) and {t for _, t in seen} == {11}


@pytest.mark.parametrize("kind", ["serial", "processes-2"])
def test_a_failed_task_names_its_job(kind):
    with executors(kind) as executor:
        with pytest.raises(InputError, match=r"^job 3: input 3: not what this task takes$"):
            list(executor.map(task_fails, [1, 2, 3, 4], describe=lambda x: f"job {x}"))
        # A bug is no user error: the serial executor raises it as it was (a debugger stops
        # there), a worker's comes back with its traceback.
        expected = ZeroDivisionError if kind == "serial" else TaskCrashed
        with pytest.raises(expected) as info:
            list(executor.map(task_fails, [4, 5, 6], describe=lambda x: f"job {x}"))
        text = str(info.value) + "".join(getattr(info.value, "__notes__", []))
        assert "job 5" in text and "division by zero in the task" in text
        if kind != "serial":
            assert "Traceback" in text and "task_fails" in text
        # The executor still works after a failure.
        assert list(executor.map(task_square, [7])) == [49]


def test_workers_run_one_thread_per_library():
    with ProcessExecutor(2) as executor:
        assert set(executor.map(task_thread_counts, range(4))) == {(1, 1, 1)}


def test_the_serial_executor_runs_single_threaded_and_restores_the_process():
    import cv2
    import torch

    before = (torch.get_num_threads(), cv2.getNumThreads())
    with SerialExecutor() as executor:
        assert list(executor.map(task_thread_counts, [0])) == [(1, 1, 1)]
    assert (torch.get_num_threads(), cv2.getNumThreads()) == before


def test_execution_config_and_command_line_options(monkeypatch):
    assert ExecutionConfig(address="auto").executor_name() == "ray"
    with pytest.raises(ValueError, match="address is for executor = 'ray'"):
        ExecutionConfig(executor="processes", address="auto")
    with pytest.raises(ValueError):
        ExecutionConfig(executor="threads")
    base = ExecutionConfig(executor="ray", address="10.0.0.1:6379", workers=8)
    assert base.updated(executor="serial") == ExecutionConfig(executor="serial", workers=8)  # the address stays with Ray
    assert base.updated(workers=None) is base
    with pytest.raises(InputError, match="--executor/--workers/--address"):
        ExecutionConfig().updated(workers=-1)
    monkeypatch.setenv("SSGA_EXECUTOR", "processes")
    assert ExecutionConfig().executor_name() == "processes"
    monkeypatch.setenv("SSGA_EXECUTOR", "gpu")
    with pytest.raises(SsgaError, match="SSGA_EXECUTOR='gpu'"):
        ExecutionConfig().executor_name()


def test_a_ray_address_where_no_cluster_answers_is_one_line(monkeypatch):
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        pytest.skip("a Ray is already running in this process")
    with pytest.raises(InputError, match="address '127.0.0.1:1': no Ray cluster answers there"):
        open_executor(ExecutionConfig(executor="ray", address="127.0.0.1:1"))


# -- a whole run, bit for bit -------------------------------------------------------------


TINY = {
    "variants": ["PDS", "SD", "D"],
    "workspace": {"name": "procedural", "seed": 3, "rooms": 3},
    "protocol": {"cells": 2, "test_per_class": 2, "val_per_class": 1, "seed": 3},
    "stages": {"parser": {"name": "slico"}, "descriptor": {"name": "dense-sift"}, "synthesizer": {"name": "depth-warp"}},
    "fuser": {"name": "rrf"},
    "training": {"epochs": 15, "hidden": 32, "synthetic_per_class": 2},
    "ensemble": {"oracle": ["SD"]},
}


def run_tiny(folder: Path, execution: dict, monkeypatch, batch: int = 5) -> dict[str, str]:
    """The tiny experiment run under ``execution``; a digest of every file it wrote, by path."""
    from ssga_bench.config import validate_experiment
    from ssga_bench.experiment import run
    from ssga_core.plugins import default_registry

    folder.mkdir()
    monkeypatch.chdir(folder)  # the workspace is built under ./runs/workspaces, each run its own
    experiment = validate_experiment({**TINY, "execution": {**execution, "batch": batch}}, default_registry())
    run(experiment=experiment, output=folder / "out")
    digests = {}
    for path in sorted(folder.rglob("*")):
        if path.is_file() and path.name not in ("timings.json", "results.png") and "cache" not in path.parts:
            data = path.read_bytes()
            if path.name == "index.html":  # all but its timings, which are the run's own
                data = data.split(b"<h2>Where the time went</h2>")[0]
            digests[str(path.relative_to(folder))] = hashlib.sha256(data).hexdigest()
    return digests


def test_a_run_is_the_same_to_the_bit_whatever_the_executor_and_workers(tmp_path, monkeypatch, local_ray):
    serial = run_tiny(tmp_path / "serial", {"executor": "serial"}, monkeypatch)
    assert any(p.endswith("scores.npy") for p in serial) and any(p.startswith("runs/workspaces/") and p.endswith(".png") for p in serial)
    for name, execution in {
        "processes-1": {"executor": "processes", "workers": 1},
        "processes-2": {"executor": "processes", "workers": 2},
        "ray": {"executor": "ray"},
    }.items():
        other = run_tiny(tmp_path / name, execution, monkeypatch)
        assert other.keys() == serial.keys(), name
        differ = [path for path in serial if other[path] != serial[path]]
        assert not differ, f"{name}: {differ[:5]}"


def test_extract_and_parse_on_worker_processes_equal_this_process(tmp_path, monkeypatch):
    """The user's images, described and parsed by two worker processes in chunks, from a relative
    path in the folder the command runs in: the same files as in this process."""
    import cv2
    import h5py
    import numpy as np
    from typer.testing import CliRunner

    from ssga_core.cli import app_with_plugin_commands

    rng = np.random.default_rng(0)
    (tmp_path / "imgs").mkdir()
    names = [f"imgs/{i}.png" for i in range(5)]
    for name in names:
        cv2.imwrite(str(tmp_path / name), rng.integers(0, 256, (256, 256, 3), dtype=np.uint8))
    monkeypatch.chdir(tmp_path)
    app, runner = app_with_plugin_commands(), CliRunner()
    outputs = {}
    for executor in ("serial", "processes"):
        common = ["--executor", executor, "--workers", "2"] if executor == "processes" else ["--executor", executor]
        extract = runner.invoke(app, ["extract", *names, "--descriptor", "dense-sift", "--out", f"{executor}.h5", *common])
        parse = runner.invoke(app, ["parse", *names, "--parser", "slico", "--out", f"{executor}-parsed", *common])
        assert extract.exit_code == 0 and parse.exit_code == 0, extract.output + parse.output
        with h5py.File(f"{executor}.h5") as h5:
            outputs[executor] = {f"{g}/{k}": h5[g][k][()].tobytes() for g in h5 for k in h5[g]}
        outputs[executor].update({p.name: p.read_bytes() for p in sorted((tmp_path / f"{executor}-parsed").iterdir())})
    assert outputs["serial"].keys() == outputs["processes"].keys() and len(outputs["serial"]) == 5 * 3 + 5 * 3
    assert outputs["serial"] == outputs["processes"]
    # A broken image is one line naming it, whichever worker met it.
    (tmp_path / "imgs" / "2.png").write_bytes(b"not a png")
    broken = runner.invoke(app, ["extract", *names, "--descriptor", "dense-sift", "--out", "broken.h5", "--executor", "processes", "--workers", "2"])
    assert broken.exit_code == 1 and "imgs/2.png: not a readable image" in broken.output and not (tmp_path / "broken.h5").exists()


INTERRUPTED_RUN = """
import sys
from ssga_core.cli.main import interrupt_on_sigterm
from ssga_bench.execution import ProcessExecutor
from ssga_bench.testing import task_write_pid_and_wait

interrupt_on_sigterm()  # as `ssga` does
try:
    with ProcessExecutor(2) as executor:
        list(executor.map(task_write_pid_and_wait, [sys.argv[1]] * 2))
except KeyboardInterrupt:
    print("interrupted")
    sys.exit(130)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_sigterm_unwinds_a_run_and_stops_its_workers(tmp_path):
    # A scheduler's time limit sends SIGTERM to the run alone: its workers, busy with
    # minute-long tasks, must stop with it instead of running on, orphaned.
    run = subprocess.Popen([sys.executable, "-c", INTERRUPTED_RUN, str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for _ in range(600):  # both workers started their task (spawning takes a few seconds)
            if len(list(tmp_path.glob("*.pid"))) == 2 or run.poll() is not None:
                break
            time.sleep(0.1)
        workers = [int(p.stem) for p in tmp_path.glob("*.pid")]
        assert len(workers) == 2, run.communicate()[1]
        run.send_signal(signal.SIGTERM)
        out, err = run.communicate(timeout=30)
    finally:
        if run.poll() is None:
            run.kill()
    assert (run.returncode, out.strip()) == (130, "interrupted"), err
    for _ in range(50):
        if not any(_alive(pid) for pid in workers):
            break
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in workers)
