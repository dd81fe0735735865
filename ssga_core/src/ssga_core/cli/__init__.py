"""The ``ssga`` command line (see :mod:`ssga_core.cli.main`)."""

from ssga_core.cli import plugins, variants  # noqa: F401 - each attaches its command to the app
from ssga_core.cli.main import app, app_with_plugin_commands, command, current_registry, main

__all__ = ["app", "app_with_plugin_commands", "command", "current_registry", "main"]
