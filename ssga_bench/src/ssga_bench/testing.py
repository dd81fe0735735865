"""Test kit of the benchmark layer.

* A stand-in workspace source: an empty square room with colour-banded walls. Register
  this module on a plugin set (or ``SSGA_PLUGIN_MODULES=ssga_bench.testing``) beside
  :mod:`ssga_core.testing.stages` to run whole experiments on stand-ins in seconds.
* :func:`interrupt_training`: a learned plugin's training command stopped mid-run, as
  its users will stop it (and then resume it).
* :func:`one_torch_thread`: torch at one thread while a test runs (with the other core
  busy, two threads wait on each other: 2-3x slower, measured).
* :func:`network_inputs` and :func:`whole_batches_on_cpu`: what a learned stage's network
  was called with, and its batched path made to run on the CPU too (to test it there).
* :class:`RunsCode`: what a malicious checkpoint holds, to show a loader never runs it.
* :func:`packaged_provenance`: a plugin's packaged weights, checked against the record beside them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import shapely
from pydantic import Field

from ssga_core import Camera, Data, Pose, StageConfig, View, WorkspaceSource, hookimpl
from ssga_core.testing import make_panorama_view, make_view
from ssga_bench.workspace import FloorPlan


class RunsCode:
    """Pickled inside a checkpoint, runs ``command`` in a shell when the file is unpickled
    unsafely: what a malicious download could hold (``weights_only`` loading refuses it)."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        import os

        return (os.system, (self.command,))


class WallConfig(StageConfig):
    size: float = Field(default=10.0, gt=1.0, description="Side of the square room, metres.")
    seed: int = 0


class WallWorkspaceSource(WorkspaceSource):
    """An empty square room painted with vertical colour bands (:func:`make_panorama_view`)."""

    name = "test-wall"
    Config = WallConfig
    produces = frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})

    def open(self) -> _WallWorkspace:
        half = self.config.size / 2
        walls = shapely.box(-half - 0.1, -half - 0.1, half + 0.1, half + 0.1).difference(shapely.box(-half, -half, half, half))
        plan = FloorPlan(free=shapely.box(-half + 0.3, -half + 0.3, half - 0.3, half - 0.3), occluders=walls)
        return _WallWorkspace(f"test-wall-{self.config.seed}", make_view().camera, plan, self.config.seed)


class _WallWorkspace:
    """Satisfies :class:`ssga_bench.Workspace`."""

    camera_height = 1.5

    def __init__(self, name: str, camera: Camera, floor_plan: FloorPlan, seed: int) -> None:
        self.name, self.camera, self.floor_plan, self.seed = name, camera, floor_plan, seed

    def render(self, pose: Pose) -> View:
        return make_panorama_view(pose, seed=self.seed)


@hookimpl
def ssga_register_workspaces() -> list[type[WorkspaceSource]]:
    return [WallWorkspaceSource]


def interrupt_training(monkeypatch: Any, run_class: type, train: Callable[[], Any], out: Path, after: int = 3) -> dict[str, Any]:
    """Run ``train()`` with ``run_class.train_step`` (a :class:`~ssga_bench.training.TrainingRun`'s)
    interrupted by ``KeyboardInterrupt`` before step ``after + 1``, as a user's Ctrl-C would; returns
    the training state it left in ``out`` (``state.pt``). The step is whole again afterwards.
    """
    from ssga_bench.learned import load_checkpoint

    real_step, taken = run_class.train_step, []

    def interrupted(self: Any, *args: Any) -> Any:
        if len(taken) == after:
            raise KeyboardInterrupt
        taken.append(1)
        return real_step(self, *args)

    monkeypatch.setattr(run_class, "train_step", interrupted)
    try:
        train()
    except KeyboardInterrupt:
        pass
    else:
        raise AssertionError(f"training ended within {after} steps: nothing was interrupted")
    finally:
        monkeypatch.setattr(run_class, "train_step", real_step)
    return load_checkpoint(out / "state.pt", "training state")


# Tasks for the executors' own tests: module-level, so a spawned worker or a Ray worker
# imports them by name, as it does the real tasks.


def task_square(x: int) -> int:
    """``x * x``: what every executor must return in job order."""
    return x * x


def task_fails(x: int) -> int:
    """A user error (a bad input) on job 3, a bug (an exception that is no user error) on job 5."""
    from ssga_core.errors import InputError

    if x == 3:
        raise InputError(f"input {x}: not what this task takes")
    if x == 5:
        raise ZeroDivisionError("division by zero in the task")
    return x


def task_write_pid_and_wait(folder: str) -> None:
    """Writes its worker's process id into ``folder``, then waits a minute: a task still
    running when its run is interrupted."""
    import os
    import time

    (Path(folder) / f"{os.getpid()}.pid").write_text(str(os.getpid()))
    time.sleep(60)


def task_thread_counts(_: object) -> tuple[int, int, int]:
    """torch, OpenCV and BLAS threads where the task runs (a worker's are all 1)."""
    import cv2
    import torch
    from threadpoolctl import threadpool_info

    blas = max((pool["num_threads"] for pool in threadpool_info()), default=1)
    return torch.get_num_threads(), cv2.getNumThreads(), blas


@contextmanager
def network_inputs(net: Any) -> Iterator[list[tuple[int, ...]]]:
    """The input shape of each call of the torch module ``net`` while the block runs (``(N, C, H, W)``:
    the batch size first). Networks are shared by every stage instance with the same weights, so
    the hook is removed after."""
    calls: list[tuple[int, ...]] = []
    handle = net.register_forward_hook(lambda module, args, out: calls.append(tuple(args[0].shape)))
    try:
        yield calls
    finally:
        handle.remove()


@contextmanager
def whole_batches_on_cpu() -> Iterator[None]:
    """Network calls take whole batches on the CPU too, as on a GPU (``ssga_bench.network_calls``),
    so that a test here runs a learned stage's batched path."""
    from ssga_bench import learned

    before = learned.CPU_VIEWS_PER_CALL
    learned.CPU_VIEWS_PER_CALL = None
    try:
        yield
    finally:
        learned.CPU_VIEWS_PER_CALL = before


@contextmanager
def one_torch_thread() -> Iterator[None]:
    """torch at one thread inside the block, as in the runner's workers; restored after."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


# Checks of the commands' failures, shared by the tests of what a command refuses or survives.


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file below ``root`` (its POSIX path relative to ``root``) and its bytes: compared before and after, what changed."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def cli_error_line(result: Any, *names: object, passing: tuple[str, ...] = ()) -> str:
    """The one ``error: ...`` line of a command that failed (typer's ``CliRunner`` result), checked: exit 1, no
    traceback, each of ``names`` in it. Progress bars and lines starting with one of ``passing`` may stand beside it."""
    assert result.exit_code == 1, (result.output, result.exception)
    # CliRunner catches what the command raised: anything but an exit is a crash with a traceback.
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    lines = [line for line in result.stderr.splitlines() if line.strip() and "━" not in line and not line.startswith(passing)]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for name in names:
        assert str(name) in lines[0], lines[0]
    return lines[0]


def read_only_below(folder: Path, write: Callable[[Path, bytes], Any]) -> Callable[[Path, bytes], Any]:
    """``write`` (:func:`ssga_bench.io.atomic_write_bytes`) refusing every file below ``folder``, as a read-only file system would."""
    import errno
    import os

    from ssga_bench.io import OutputError

    def read_only(path: Path, data: bytes) -> Any:
        if Path(path).resolve().is_relative_to(folder.resolve()):
            raise OutputError(f"{path}: cannot write: {os.strerror(errno.EROFS)}")
        return write(path, data)

    return read_only


def plugin_with(*classes: type, hook: str = "ssga_register_parsers") -> Any:
    """A throwaway plugin object implementing one registration hook, ``hook``, that registers ``classes``."""

    class Plugin:
        pass

    def register() -> list[type]:
        return list(classes)

    register.__name__ = hook
    setattr(Plugin, hook, staticmethod(hookimpl(register)))
    return Plugin()


def check_installed(registry: Any, kind: str, name: str, cls: type, distribution: str) -> None:
    """``cls`` is the ``kind`` plugin ``name`` of the installed distribution ``distribution``, in ``registry`` (the
    ``ssga_installed_registry`` fixture's) and in the default plugin manager's."""
    from ssga_core.plugins import get_plugin_manager

    entry = registry.entry(kind, name)
    assert entry.cls is cls
    assert entry.plugin.distribution == distribution
    assert get_plugin_manager().registry().get(kind, name) is cls


def packaged_provenance(path: Path, module: str, max_bytes: int = 20_000_000) -> dict[str, Any]:
    """The provenance inside the packaged weights ``path`` (a ``NAME.pt`` of
    :func:`~ssga_bench.training.export_checkpoint`), checked: ``NAME.json`` beside it gives the
    file's SHA-256 and size, the file is at most ``max_bytes``, and ``python -m module`` made it."""
    import hashlib
    import json

    import torch

    data = path.read_bytes()
    sidecar = json.loads(path.with_suffix(".json").read_text())
    assert sidecar["sha256"] == hashlib.sha256(data).hexdigest() and sidecar["bytes"] == len(data) <= max_bytes
    provenance: dict[str, Any] = torch.load(path, weights_only=True)["provenance"]
    assert provenance["command"].startswith(f"python -m {module}")
    return provenance


def one_line_checkpoint_error(make: Callable[[], Any], *fragments: str) -> str:
    """The :class:`~ssga_core.CheckpointError` that ``make()`` raises, checked: one line, each of ``fragments`` in it; its message."""
    import pytest

    from ssga_core.errors import CheckpointError

    with pytest.raises(CheckpointError) as err:
        make()
    message = str(err.value)
    assert "\n" not in message, message
    for fragment in fragments:
        assert fragment in message, message
    return message
