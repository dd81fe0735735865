"""The benchmark layer's commands, joining the ``ssga`` app through the core's hook.

Kept light: the command modules import the heavy parts (torch, OpenCV) inside the
commands, so ``ssga --help`` and ``ssga variants --list`` stay fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from ssga_core import hookimpl


@hookimpl
def ssga_register_commands(app: typer.Typer) -> None:
    from ssga_bench.cli import compare, config, extract, parse, run, synthesize, workspace

    for module in (config, run, workspace, extract, synthesize, parse, compare):
        module.register(app)


@hookimpl
def ssga_read_config(path: Path) -> tuple[dict[str, Any], Path]:
    """Experiment configs as every ssga command reads them: a packaged one by name, ``preset`` applied."""
    from ssga_bench.config import read_experiment

    return read_experiment(path)

