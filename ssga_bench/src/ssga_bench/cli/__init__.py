"""The benchmark layer's commands (``run``, ``demo``, ``bench``, ``workspace``, ``config``, ``extract``, ``synthesize``, ``parse``).

Each module has a ``register(app)`` that the plugin hook calls; each command is a thin
wrapper over a keyword-only library function of :mod:`ssga_bench`.
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated, Any

import typer

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from ssga_bench.execution import EXECUTORS, ExecutionConfig
from ssga_core.errors import InputError


class Bars:
    """Progress bars for the library's ``progress(phase, done, total)`` callbacks, one bar per phase."""

    def __init__(self, progress: Progress, console: Console) -> None:
        self._progress = progress
        self._console = console
        self._tasks: dict[str, Any] = {}

    def __call__(self, phase: str, done: int, total: int) -> None:
        if phase not in self._tasks:
            self._tasks[phase] = self._progress.add_task(phase, total=total)
        self._progress.update(self._tasks[phase], completed=done, total=total)

    def variant(self, label: str) -> None:
        """A variant finished (on whichever worker): say which."""
        self._console.print(f"done: {label}")


@contextmanager
def progress_bars(*, transient: bool = True) -> Iterator[Bars]:
    console = Console(stderr=True)
    columns = (TextColumn("{task.description:<32}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns, console=console, transient=transient) as progress:
        yield Bars(progress, console)


ExecutorOption = Annotated[
    str | None,
    typer.Option("--executor", metavar="serial|processes|ray", help="Where the work runs [default: the config's [execution], else processes on every core]."),
]
WorkersOption = Annotated[int | None, typer.Option("--workers", min=0, metavar="N", help="Workers (0: every core, or every CPU of the Ray cluster).")]
MaxSideOption = Annotated[
    int,
    typer.Option(
        "--max-side",
        min=0,
        metavar="PX",
        help="An image whose longest side is larger is read reduced to it (a 12000 x 12000 photo is never decoded whole), "
        "and said so; 0: every image at its own size.",
    ),
]
AddressOption = Annotated[str | None, typer.Option("--address", metavar="HOST:PORT", help="--executor ray: the Ray cluster to join ('auto' or the head's address).")]


def execution_options(config: ExecutionConfig | None, executor: str | None, workers: int | None, address: str | None) -> ExecutionConfig:
    """A config's ``[execution]`` (or the default) with the command line's options over it."""
    if executor is not None and executor not in EXECUTORS:
        raise InputError(f"--executor {executor!r}: expected one of {', '.join(EXECUTORS)}")
    return (config or ExecutionConfig()).updated(executor=executor, workers=workers, address=address)


def parse_option(text: str) -> tuple[str, Any]:
    """``key=value`` with a TOML value (``rooms=5``, ``shading=false``, ``path="a b.glb"``), or a bare string."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise InputError(f"--option {text!r}: expected key=value")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return key.strip(), parsed
