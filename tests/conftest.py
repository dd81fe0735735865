"""Shared fixtures for ssga's own tests (plugin authors get theirs from ssga_core.testing)."""

from __future__ import annotations

import pytest

from ssga_core.plugins import Registry
from ssga_core.testing import stages as stand_in_stages
from ssga_bench import testing as stand_in_workspaces


@pytest.fixture
def stand_in_registry(ssga_plugin_set) -> Registry:
    """A registry of the stand-in stages and the installed fusers' kind of plugin: nothing installed."""
    ssga_plugin_set.register(stand_in_stages, "stand-ins")
    ssga_plugin_set.register(stand_in_workspaces, "stand-in-workspaces")
    return ssga_plugin_set.registry()


@pytest.fixture
def stand_ins(monkeypatch, ssga_plugin_set) -> Registry:
    """Make the CLI see the stand-in stages and workspace plus the installed plugins."""
    ssga_plugin_set.load_entry_points()
    ssga_plugin_set.register(stand_in_stages, "stand-ins")
    ssga_plugin_set.register(stand_in_workspaces, "stand-in-workspaces")
    registry = ssga_plugin_set.registry()
    monkeypatch.setattr("ssga_core.plugins.default_registry", lambda: registry)
    return registry
