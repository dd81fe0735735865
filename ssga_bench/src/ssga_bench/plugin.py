"""The benchmark layer's commands, joining the ``ssga`` app through the core's hook.

Kept light: the command modules import the heavy parts (torch, OpenCV) inside the
commands, so ``ssga --help`` and ``ssga variants --list`` stay fast.
"""

from __future__ import annotations

import typer

from ssga_core import hookimpl


@hookimpl
def ssga_register_commands(app: typer.Typer) -> None:
    from ssga_bench.cli import config, extract, parse, run, synthesize, workspace

    for module in (config, run, workspace, extract, synthesize, parse):
        module.register(app)
