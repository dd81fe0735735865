"""Test kit for ssga plugin authors, installed as a pytest plugin with ssga-core.

Fixtures (available in any test once ssga-core is installed):

* ``ssga_plugin_set``: a fresh plugin manager with ssga's hooks and no plugins loaded;
  register throwaway plugins on it and build a registry with ``.registry()``.
* ``ssga_installed_registry``: the registry of the plugins installed in this
  environment (failures of other plugins are in its ``failures``).
* ``fake_entry_points``: make :func:`ssga_core.plugins.get_plugin_manager` see the
  entry points you give it instead of the installed ones.

Helpers: :func:`make_view` (a deterministic view with depth and semantic ids), stand-in
stages (:mod:`ssga_core.testing.stages`) and contract checks
(:mod:`ssga_core.testing.contracts`) that run your stage alone and in every variant order.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from ssga_core.plugins import PluginSet, Registry, get_plugin_manager
from ssga_core.testing.contracts import (
    check_descriptor,
    check_descriptor_in_all_orders,
    check_fuser,
    check_parser,
    check_parser_in_all_orders,
    check_synthesizer,
    check_synthesizer_in_all_orders,
)
from ssga_core.testing.views import make_panorama_view, make_view

__all__ = [
    "FakeDistribution",
    "FakeEntryPoint",
    "check_descriptor",
    "check_descriptor_in_all_orders",
    "check_fuser",
    "check_parser",
    "check_parser_in_all_orders",
    "check_synthesizer",
    "check_synthesizer_in_all_orders",
    "get_plugin_manager",
    "make_panorama_view",
    "make_view",
]


@dataclass(frozen=True)
class FakeDistribution:
    """Stands in for an installed distribution's metadata."""

    name: str = "fake-plugin"
    version: str = "0.0.1"

    @property
    def metadata(self) -> dict[str, str]:
        return {"Name": self.name}


@dataclass(frozen=True)
class FakeEntryPoint:
    """An ``ssga`` entry point whose ``load()`` returns ``plugin`` (or raises it, if an exception)."""

    name: str
    plugin: Any
    dist: FakeDistribution = FakeDistribution()
    value: str = "fake_module:plugin"
    group: str = "ssga"

    def load(self) -> Any:
        if isinstance(self.plugin, BaseException):
            raise self.plugin
        return self.plugin


@pytest.fixture
def ssga_plugin_set() -> PluginSet:
    """A fresh plugin manager with ssga's hookspecs and no plugin loaded."""
    return get_plugin_manager(load_entrypoints=False)


@pytest.fixture
def ssga_installed_registry() -> Registry:
    """The registry of the installed plugins.

    Other installed plugins that fail to load are in ``registry.failures``, not test
    failures: a plugin's own tests should not break because of someone else's plugin.
    """
    return get_plugin_manager().registry()


@pytest.fixture
def fake_entry_points(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., None]]:
    """Call with :class:`FakeEntryPoint` objects to make them the only installed ``ssga`` entry points."""

    def install(*entry_points: FakeEntryPoint) -> None:
        monkeypatch.setattr("ssga_core.plugins.metadata.entry_points", lambda group: list(entry_points))

    yield install
