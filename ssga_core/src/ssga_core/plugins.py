"""Finding plugins and building the registry of stage implementations.

Discovery, in order:

1. :func:`get_plugin_manager` adds the hookspecs of :mod:`ssga_core.hookspecs`.
2. Unless ``SSGA_DISABLE_PLUGIN_AUTOLOAD`` is set, each entry point of the ``ssga``
   group is imported and registered on its own, so one plugin that fails to import
   (or implements a hook that does not exist, or with wrong arguments) is reported by
   name, distribution and version, and the others still load. ``SSGA_PLUGINS=a,b``
   loads only the entry points or distributions named. ``SSGA_STRICT_PLUGINS=1``
   (set in CI) turns any such failure into an error.
3. :class:`Registry` calls every ``ssga_register_*`` hook once and indexes the returned
   classes by ``(kind, name)``. Two plugins giving one name is an error naming both.

``SSGA_PLUGIN_MODULES=my_parser,other.module`` also imports and registers those modules
(from the current directory or anywhere on ``sys.path``): the quickest way to try a plugin
before packaging it. ``SSGA_TRACE_PLUGINS=1`` prints every hook call to stderr.
"""

from __future__ import annotations

import importlib
import importlib.metadata as metadata
import inspect
import os
import re
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import pluggy
from pydantic import BaseModel

from ssga_core import hookspecs
from ssga_core.errors import PluginError, UnknownStageError
from ssga_core.kinds import KIND_NAMES, KINDS, kind_named
from ssga_core.stages import Stage, StageConfig

ENTRY_POINT_GROUP = "ssga"

_NAME = re.compile(r"^[a-z0-9][a-z0-9_.-]*$")


@dataclass(frozen=True)
class PluginInfo:
    """Where a registered plugin came from."""

    name: str
    """Its registration name: the entry-point name, or the name given to ``register``."""
    distribution: str = ""
    version: str = ""

    def describe(self) -> str:
        if not self.distribution:
            return f"plugin {self.name!r}"
        # A module from SSGA_PLUGIN_MODULES has no version and a distribution already in
        # parentheses: "(SSGA_PLUGIN_MODULES)", not "((SSGA_PLUGIN_MODULES) )".
        where = " ".join(part for part in (self.distribution.strip("()"), self.version) if part)
        return f"plugin {self.name!r} ({where})"


@dataclass(frozen=True)
class PluginFailure:
    """A plugin that could not be loaded or registered, and why (one line)."""

    plugin: PluginInfo
    reason: str

    def __str__(self) -> str:
        return f"{self.plugin.describe()} failed to load: {self.reason}"


@dataclass(frozen=True)
class StageEntry:
    """One stage implementation in the registry."""

    kind: str
    name: str
    cls: type[Stage]
    plugin: PluginInfo


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _env_flag(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() not in ("", "0", "false", "no")


@dataclass
class PluginSet:
    """A plugin manager with the provenance of each plugin and the failures met loading them."""

    pm: pluggy.PluginManager
    infos: dict[str, PluginInfo] = field(default_factory=dict)
    failures: list[PluginFailure] = field(default_factory=list)

    def register(self, plugin: Any, name: str | None = None, *, info: PluginInfo | None = None) -> bool:
        """Register ``plugin`` (a module or object with hook implementations).

        Returns whether it was registered; a plugin with an invalid hook
        implementation is recorded in :attr:`failures` instead.
        """
        name = name or getattr(plugin, "__name__", None) or type(plugin).__name__
        info = info or PluginInfo(name=name)
        try:
            self.pm.register(plugin, name=name)
        except (pluggy.PluginValidationError, ValueError) as exc:
            self.failures.append(PluginFailure(info, one_line(exc)))
            return False
        unknown = [h.name for h in self.pm.get_hookcallers(plugin) or [] if not h.has_spec()]
        if unknown:
            self.pm.unregister(plugin)
            known = ", ".join(_hook_names())
            reason = f"implements unknown hook(s) {', '.join(sorted(unknown))}; ssga's hooks are {known}"
            self.failures.append(PluginFailure(info, reason))
            return False
        self.infos[name] = info
        return True

    def load_entry_points(self, entry_points: Iterable[metadata.EntryPoint] | None = None) -> None:
        """Import and register each ``ssga`` entry point, recording failures per plugin."""
        allow = {s.strip() for s in os.environ.get("SSGA_PLUGINS", "").split(",") if s.strip()}
        if entry_points is None:
            entry_points = metadata.entry_points(group=ENTRY_POINT_GROUP)
        for ep in entry_points:
            dist = ep.dist
            info = PluginInfo(
                name=ep.name,
                distribution=dist.metadata["Name"] if dist is not None else "",
                version=dist.version if dist is not None else "",
            )
            if allow and ep.name not in allow and info.distribution not in allow:
                continue
            if self.pm.has_plugin(ep.name):
                continue
            plugin = self._import(ep.load, ep.value, info)
            if plugin is not None:
                self.register(plugin, ep.name, info=info)

    def load_modules(self, names: Iterable[str]) -> None:
        """Import and register plugin modules by dotted name, recording failures per module.

        The current directory is searched too, but *after* everything installed: the
        user asked for these modules by name, and a stray ``torch.py`` in the working
        directory must not shadow the real one.
        """
        names = list(names)
        if names and os.getcwd() not in sys.path:
            sys.path.append(os.getcwd())
        for name in names:
            info = PluginInfo(name=name, distribution="(SSGA_PLUGIN_MODULES)")
            module = self._import(lambda: importlib.import_module(name), name, info)
            # A module an entry point already registered (naming an installed plugin) is
            # the same object: registering it twice would only clash with itself.
            if module is not None and not self.pm.is_registered(module):
                self.register(module, name, info=info)

    def _import(self, load: Any, what: str, info: PluginInfo) -> Any:
        """``load()``, or None with the failure recorded; a plugin cannot end ssga by exiting."""
        try:
            return load()
        except SystemExit as exc:
            self.failures.append(PluginFailure(info, f"importing {what} called sys.exit({exc.code!r})"))
        except Exception as exc:  # noqa: BLE001 - any import failure is the plugin's, reported by name
            self.failures.append(PluginFailure(info, f"cannot import {what}: {one_line(exc)}"))
        return None

    def registry(self) -> Registry:
        """Call every registration hook and index the classes (see :class:`Registry`)."""
        return Registry.build(self)


def get_plugin_manager(*, load_entrypoints: bool = True) -> PluginSet:
    """A fresh plugin manager with ssga's hookspecs, and (by default) the installed plugins.

    Args:
        load_entrypoints: load the ``ssga`` entry points of installed distributions;
            ignored (treated as false) when ``SSGA_DISABLE_PLUGIN_AUTOLOAD`` is set.
    """
    pm = pluggy.PluginManager("ssga")
    pm.add_hookspecs(hookspecs)
    if _env_flag("SSGA_TRACE_PLUGINS"):
        pm.trace.root.setwriter(lambda msg: sys.stderr.write(str(msg)))
        pm.enable_tracing()
    plugins = PluginSet(pm)
    if load_entrypoints and not _env_flag("SSGA_DISABLE_PLUGIN_AUTOLOAD"):
        plugins.load_entry_points()
    modules = [m.strip() for m in os.environ.get("SSGA_PLUGIN_MODULES", "").split(",") if m.strip()]
    plugins.load_modules(modules)
    return plugins


@lru_cache(maxsize=1)
def default_plugins() -> PluginSet:
    """The installed plugins, loaded once per process (for the CLI)."""
    return get_plugin_manager()


@lru_cache(maxsize=1)
def default_registry() -> Registry:
    """The registry of installed plugins, built once per process (for the CLI).

    Plugin failures are warnings on stderr, or an error under ``SSGA_STRICT_PLUGINS=1``.
    Library functions take a registry as an argument instead; tests build their own
    with :func:`get_plugin_manager`.
    """
    registry = default_plugins().registry()
    if registry.failures:
        if _env_flag("SSGA_STRICT_PLUGINS"):
            raise PluginError("; ".join(map(str, registry.failures)) + " (SSGA_STRICT_PLUGINS is set)")
        for failure in registry.failures:
            print(f"warning: {failure}", file=sys.stderr)
    return registry


def plugin_rows(registry: Registry) -> list[dict[str, Any]]:
    """One row per registered stage implementation: where it comes from, what it does, its config."""
    return [
        {
            "distribution": entry.plugin.distribution,
            "version": entry.plugin.version,
            "entry_point": entry.plugin.name,
            "kind": entry.kind,
            "name": entry.name,
            "abbrev": entry.cls.abbrev,
            "class": f"{entry.cls.__module__}.{entry.cls.__qualname__}",
            "consumes": sorted(str(d) for d in entry.cls.consumes),
            "produces": sorted(str(d) for d in entry.cls.produces),
            "presets": sorted(entry.cls.presets),
            # Checkpoint layouts a learned stage recognises (ssga_bench's Learned kit declares them).
            "layouts": [{"name": layout.name, "source": layout.source} for layout in getattr(entry.cls, "layouts", ())],
            "config_schema": entry.cls.Config.model_json_schema(),
        }
        for entry in registry
    ]


def _hook_names() -> list[str]:
    return sorted(name for name in dir(hookspecs) if name.startswith("ssga_"))


def _check_stage_class(kind: str, cls: object) -> str | None:
    """Why ``cls`` is not a valid implementation of ``kind``, or None."""
    base = kind_named(kind).base
    if not (inspect.isclass(cls) and issubclass(cls, base)):
        return f"returned {cls!r} from {kind_named(kind).hook}, which is not a subclass of ssga_core.{base.__name__}"
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not _NAME.match(name):
        return f"{kind} class {cls.__name__} needs a `name` of lower-case letters, digits, '.', '_' or '-', got {name!r}"
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        return f"{kind} {name!r} ({cls.__name__}) does not implement {missing}"
    config = cls.Config
    if not (inspect.isclass(config) and issubclass(config, StageConfig)):
        return f"{kind} {name!r}: Config must subclass ssga_core.StageConfig, got {config!r}"
    if issubclass(config, BaseModel) and config.model_config.get("extra") != "forbid":
        return f"{kind} {name!r}: Config must keep extra='forbid' so misspelled keys are errors"
    return None


class Registry:
    """Stage implementations by kind and name, with the plugin each came from."""

    def __init__(self, entries: Iterable[StageEntry], failures: Iterable[PluginFailure] = ()) -> None:
        self._entries: dict[tuple[str, str], StageEntry] = {}
        for entry in entries:
            key = (entry.kind, entry.name)
            if key in self._entries:
                first = self._entries[key]
                raise PluginError(
                    f"{entry.kind} name {entry.name!r} is registered twice: by {first.plugin.describe()} "
                    f"({first.cls.__module__}.{first.cls.__qualname__}) and by {entry.plugin.describe()} "
                    f"({entry.cls.__module__}.{entry.cls.__qualname__}); uninstall one of them"
                )
            self._entries[key] = entry
        self.failures: list[PluginFailure] = list(failures)

    @classmethod
    def build(cls, plugins: PluginSet) -> Registry:
        entries: list[StageEntry] = []
        failures = list(plugins.failures)
        # Each implementation is called on its own, to know which plugin gave which class;
        # that bypasses pluggy's hook-call monitoring, so trace here (SSGA_TRACE_PLUGINS).
        trace = plugins.pm.trace.root.get("hook")
        for kind, hook in ((k.name, k.hook) for k in KINDS):
            for impl in getattr(plugins.pm.hook, hook).get_hookimpls():
                info = plugins.infos.get(impl.plugin_name, PluginInfo(impl.plugin_name))
                try:
                    classes = list(impl.function() or [])
                    trace(f"{hook} [{impl.plugin_name}] ->", [getattr(c, "name", c) for c in classes])
                except (Exception, SystemExit) as exc:  # noqa: BLE001 - a broken plugin must not hide the others
                    failures.append(PluginFailure(info, f"{hook}() raised {one_line(exc)}"))
                    continue
                problems = [p for p in (_check_stage_class(kind, c) for c in classes) if p]
                if problems:
                    failures.append(PluginFailure(info, "; ".join(problems)))
                    continue
                entries.extend(StageEntry(kind, c.name, c, info) for c in classes)
        return cls(entries, failures)

    def __iter__(self) -> Iterator[StageEntry]:
        return iter(sorted(self._entries.values(), key=lambda e: (KIND_NAMES.index(e.kind), e.name)))

    def names(self, kind: str) -> list[str]:
        return sorted(name for (k, name) in self._entries if k == kind)

    def entry(self, kind: str, name: str) -> StageEntry:
        try:
            return self._entries[(kind, name)]
        except KeyError:
            known = ", ".join(self.names(kind)) or "none installed"
            raise UnknownStageError(f"no {kind} named {name!r}; known {kind}s: {known}") from None

    def get(self, kind: str, name: str) -> type[Stage]:
        """The class registered as ``name`` for ``kind``; unknown names list the known ones."""
        return self.entry(kind, name).cls

    def create(self, kind: str, name: str, **params: Any) -> Stage:
        """An instance of ``name`` with ``params`` validated by its Config."""
        cls = self.get(kind, name)
        return cls(cls.Config.model_validate(params))

