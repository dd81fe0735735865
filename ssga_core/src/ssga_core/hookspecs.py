"""The hooks an ssga plugin implements.

A plugin is a module (or object) registered under the ``ssga`` entry-point group that
implements one or more of these hooks with :data:`ssga_core.hookimpl`. Every
``ssga_register_<kind>s`` hook (one per stage kind, :mod:`ssga_core.kinds`) is called
once, when the plugin manager builds its :class:`~ssga_core.plugins.Registry` (at the
start of each CLI command), with no arguments, and returns a list of classes;
:func:`ssga_register_commands` is called once when the ``ssga`` command starts. Import heavy dependencies (torch models, OpenCV contrib...) *inside* your
stage's methods or inside the hook, not at module top, so listing plugins stays fast
and one broken dependency does not hide the rest.

A class's ``name`` must be unique within its kind across all installed plugins; two
plugins registering the same name is an error naming both.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import pluggy

from ssga_core.stages import Descriptor, Fuser, Parser, Synthesizer, WorkspaceSource

if TYPE_CHECKING:
    import typer

hookspec = pluggy.HookspecMarker("ssga")


@hookspec
def ssga_register_parsers() -> list[type[Parser]]:
    """Scene parsers (stage P) this plugin provides.

    :return: subclasses of :class:`ssga_core.Parser`, each with a unique ``name``.
    """


@hookspec
def ssga_register_descriptors() -> list[type[Descriptor]]:
    """Scene descriptors (stage D) this plugin provides.

    :return: subclasses of :class:`ssga_core.LocalDescriptor` (features at pixel
        positions, usable in every order) or :class:`ssga_core.RegionDescriptor`
        (features of given regions, not usable where description precedes parsing
        or synthesis).
    """


@hookspec
def ssga_register_synthesizers() -> list[type[Synthesizer]]:
    """View synthesizers (stage S) this plugin provides.

    :return: subclasses of :class:`ssga_core.Synthesizer`.
    """


@hookspec
def ssga_register_fusers() -> list[type[Fuser]]:
    """Late-fusion rules combining the class scores of several variants.

    :return: subclasses of :class:`ssga_core.Fuser`.
    """


@hookspec
def ssga_register_workspaces() -> list[type[WorkspaceSource]]:
    """Workspace sources: generated scenes, mesh renderers, folders of captured images.

    :return: subclasses of :class:`ssga_core.WorkspaceSource`.
    """


@hookspec
def ssga_register_commands(app: typer.Typer) -> None:
    """Add commands to the ``ssga`` command line (as datasette's ``register_commands``).

    Called once when the ``ssga`` command starts, before its arguments are parsed.
    Attach commands with ``app.command()`` or sub-apps with ``app.add_typer()``; wrap
    each in :func:`ssga_core.cli.command` so user errors print as one line. Keep the
    module that implements this hook light to import: heavy imports belong inside the
    commands, so ``ssga --help`` stays fast.

    :param app: the ``ssga`` typer app.
    """


@hookspec(firstresult=True)
def ssga_read_config(path: Path) -> tuple[dict[str, Any], Path] | None:
    """An experiment config as the core's commands (``ssga variants --config``) should see it.

    For a plugin that layers configs, as ssga-bench does (a packaged experiment named
    instead of a path, ``preset = "NAME"`` under a file's own keys). The first plugin
    to answer wins; with none, the core reads the file as plain TOML.

    :param path: what the user gave: a file, or a name the plugin may know.
    :return: the config's contents with its layers applied, and the file they came
        from (relative paths in it are taken from that file's folder); or None when
        the plugin has nothing to say about ``path``.
    """

