"""The ``ssga`` app, the error handling every command shares, and the console-script entry point.

Commands live one per module beside this one and attach themselves to :data:`app` when
:mod:`ssga_core.cli` is imported; plugins add theirs through the
``ssga_register_commands`` hook (the benchmark layer's ``run``, ``demo``, ``bench``,
``workspace`` and ``config`` come that way). Each command is a thin wrapper: it parses
options and calls a keyword-only library function.
"""

from __future__ import annotations

import functools
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import typer

from ssga_core import plugins
from ssga_core.errors import SsgaError

NAME = "ssga"
HELP = "Synthetic scene-graph augmentation for cross-view image localization."

# rich_markup_mode=None: help texts are plain text, so "[workspace]" or "[default: x]"
# in a help string is printed as written instead of being taken for markup and dropped.
app = typer.Typer(
    name=NAME, help=HELP, no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None
)

F = TypeVar("F", bound=Callable[..., Any])


def reports_user_errors(func: F) -> F:
    """Print a user error on stderr as one line and exit 1, without a traceback.

    User errors are :class:`SsgaError` and what the file system refuses (a read-only
    folder, a full disk): those are the user's environment, not ssga's bugs.
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except SsgaError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1) from None
        except OSError as exc:
            where = f"{exc.filename}: " if exc.filename else ""
            typer.echo(f"error: {where}{exc.strerror or exc}", err=True)
            raise typer.Exit(1) from None

    return wrapper  # type: ignore[return-value]


def command(parent: typer.Typer = app, **kwargs: Any) -> Callable[[F], F]:
    """Register a CLI command that reports user errors as one line (for plugins' commands too)."""

    def register(func: F) -> F:
        wrapped = reports_user_errors(func)
        parent.command(**kwargs)(wrapped)
        return wrapped

    return register


def current_registry() -> plugins.Registry:
    """The registry of installed plugins, for commands (tests replace ``plugins.default_registry``)."""
    return plugins.default_registry()


def read_config(path: Path) -> tuple[dict[str, Any], Path]:
    """An experiment config as the installed plugins layer it (``ssga_read_config``), else the file as plain TOML."""
    from ssga_core.config import read_toml

    layered = plugins.default_plugins().pm.hook.ssga_read_config(path=path)
    return layered if layered is not None else (read_toml(path), path)


_plugin_commands_added = False


def app_with_plugin_commands(plugin_set: plugins.PluginSet | None = None) -> typer.Typer:
    """:data:`app` with every plugin's commands attached (once per process)."""
    global _plugin_commands_added
    if _plugin_commands_added:
        return app
    _plugin_commands_added = True
    plugin_set = plugin_set or plugins.default_plugins()
    for impl in plugin_set.pm.hook.ssga_register_commands.get_hookimpls():
        try:
            impl.function(app=app)
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - a broken plugin must not take the others down
            info = plugin_set.infos.get(impl.plugin_name, plugins.PluginInfo(impl.plugin_name))
            plugin_set.failures.append(plugins.PluginFailure(info, f"ssga_register_commands() raised {plugins.one_line(exc)}"))
    return app


def interrupt_on_sigterm() -> None:
    """Make SIGTERM (``kill``, a scheduler's time limit or preemption) unwind the program as
    Ctrl-C does, so every ``with`` and ``finally`` runs: workers are stopped, half-written
    files are not left behind, and a resumed run continues where this one stopped. Python's
    default ends the process at once and leaves its worker processes running."""

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)


def main() -> None:
    """Console-script entry point."""
    interrupt_on_sigterm()
    try:
        cli = app_with_plugin_commands()
    except SsgaError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
    cli()
