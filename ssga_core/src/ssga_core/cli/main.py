"""The ``ssga`` app and the error handling every command shares."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import typer

from ssga_core.errors import SsgaError

NAME = "ssga"
HELP = "Synthetic scene-graph augmentation for cross-view image localization."

app = typer.Typer(name=NAME, help=HELP, no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False)

F = TypeVar("F", bound=Callable[..., Any])


def reports_user_errors(func: F) -> F:
    """Print an :class:`SsgaError` as ``error: ...`` on stderr and exit 1, without a traceback."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except SsgaError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1) from None

    return wrapper  # type: ignore[return-value]


def command(parent: typer.Typer = app, **kwargs: Any) -> Callable[[F], F]:
    """Register a CLI command that reports user errors as one line."""

    def register(func: F) -> F:
        wrapped = reports_user_errors(func)
        parent.command(**kwargs)(wrapped)
        return wrapped

    return register


def _register_commands() -> None:
    # Imported for their side effect of attaching commands to `app`.
    from ssga_core.cli import config, plugins, run, variants, workspace  # noqa: F401


_register_commands()


def main() -> None:
    """Console-script entry point."""
    app()
