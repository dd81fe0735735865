"""Discovery through entry points, failures reported per plugin, registry checks."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import pytest

from ssga_core import Parser, PluginError, StageConfig, hookimpl
from ssga_core.errors import UnknownStageError
from ssga_core.plugins import get_plugin_manager
from ssga_core.testing import FakeDistribution, FakeEntryPoint
from ssga_core.testing.stages import StripesParser
from ssga_bench.testing import plugin_with

REPO = Path(__file__).resolve().parents[2]


def test_every_installed_plugin_of_the_repository_loads(ssga_installed_registry):
    assert not ssga_installed_registry.failures, "; ".join(map(str, ssga_installed_registry.failures))


def test_installed_plugins_are_found_through_their_entry_points(ssga_installed_registry):
    grid = ssga_installed_registry.entry("parser", "grid")
    assert (grid.plugin.distribution, grid.plugin.name) == ("ssga-parser-grid", "parser_grid")
    assert ssga_installed_registry.entry("fuser", "rrf").plugin.distribution == "ssga-fuser-rrf"


def test_every_package_in_the_repository_is_installed_with_one_entry_point():
    """Catches a plugin folder that set-up does not install or whose entry point is missing."""
    folders = sorted(p.parent for p in REPO.glob("plugins/*/*/pyproject.toml")) + sorted(p.parent for p in REPO.glob("examples/*/pyproject.toml"))
    eps = {ep.dist.metadata["Name"]: ep for ep in importlib.metadata.entry_points(group="ssga")}
    for folder in folders:
        assert folder.name in eps, f"{folder.relative_to(REPO)} is not installed (run make setup) or has no ssga entry point"
    assert len([d for d in importlib.metadata.distributions() if d.entry_points.select(group="ssga")]) >= len(folders)


def test_a_plugin_that_fails_to_import_is_reported_and_the_others_load(fake_entry_points):
    fake_entry_points(
        FakeEntryPoint("parser_broken", ImportError("No module named 'detectron2'"), FakeDistribution("ssga-parser-broken", "0.3")),
        FakeEntryPoint("parser_stripes", plugin_with(StripesParser), FakeDistribution("ssga-parser-stripes", "1.0")),
    )
    registry = get_plugin_manager().registry()
    assert registry.names("parser") == ["test-stripes"]
    (failure,) = registry.failures
    assert str(failure) == (
        "plugin 'parser_broken' (ssga-parser-broken 0.3) failed to load: "
        "cannot import fake_module:plugin: ImportError: No module named 'detectron2'"
    )


def test_unknown_hooks_are_caught(ssga_plugin_set):
    class Typo:
        @hookimpl
        def ssga_register_parser(self):  # missing "s"
            return []

    assert not ssga_plugin_set.register(Typo(), "typo")
    assert "unknown hook(s) ssga_register_parser" in ssga_plugin_set.failures[0].reason
    assert not ssga_plugin_set.pm.has_plugin("typo")


def test_hook_implementations_with_wrong_arguments_are_caught(ssga_plugin_set):
    class Wrong:
        @hookimpl
        def ssga_register_parsers(self, registry):
            return []

    assert not ssga_plugin_set.register(Wrong(), "wrong")
    assert "registry" in ssga_plugin_set.failures[0].reason


def test_two_plugins_claiming_one_name_is_an_error_naming_both(fake_entry_points):
    class Other(StripesParser):
        pass

    fake_entry_points(
        FakeEntryPoint("a", plugin_with(StripesParser), FakeDistribution("ssga-parser-a", "1.0")),
        FakeEntryPoint("b", plugin_with(Other), FakeDistribution("ssga-parser-b", "2.0")),
    )
    with pytest.raises(PluginError) as info:
        get_plugin_manager().registry()
    message = str(info.value)
    assert "parser name 'test-stripes' is registered twice" in message
    assert "(ssga-parser-a 1.0)" in message and "(ssga-parser-b 2.0)" in message


class Loose(StageConfig):
    model_config = {"extra": "allow"}


class NoName(StripesParser):
    name = "Bad Name"


class Abstract(Parser):
    name = "abstract"


class LooseConfig(StripesParser):
    name = "loose"
    Config = Loose


@pytest.mark.parametrize(
    ("cls", "reason"),
    [
        (int, "not a subclass of ssga_core.Parser"),
        (NoName, "needs a `name` of lower-case letters"),
        (Abstract, "does not implement _parse"),
        (LooseConfig, "must keep extra='forbid'"),
    ],
)
def test_invalid_registrations_are_reported_per_plugin(ssga_plugin_set, cls, reason):
    ssga_plugin_set.register(plugin_with(cls, StripesParser), "bad")
    registry = ssga_plugin_set.registry()
    assert registry.names("parser") == []  # the whole plugin is refused, not half of it
    assert reason in registry.failures[0].reason


def test_a_hook_that_raises_is_reported(ssga_plugin_set):
    class Raising:
        @hookimpl
        def ssga_register_parsers(self):
            raise RuntimeError("boom")

    ssga_plugin_set.register(Raising(), "raising")
    registry = ssga_plugin_set.registry()
    assert "ssga_register_parsers() raised RuntimeError: boom" in registry.failures[0].reason


def test_unknown_names_list_the_known_ones(stand_in_registry):
    with pytest.raises(UnknownStageError, match="no parser named 'slic'; known parsers: test-stripes"):
        stand_in_registry.get("parser", "slic")


def test_allow_list_and_autoload_switch(fake_entry_points, monkeypatch):
    fake_entry_points(
        FakeEntryPoint("a", plugin_with(StripesParser), FakeDistribution("ssga-parser-a")),
        FakeEntryPoint("b", ImportError("never imported"), FakeDistribution("ssga-parser-b")),
    )
    monkeypatch.setenv("SSGA_PLUGINS", "ssga-parser-a")
    registry = get_plugin_manager().registry()
    assert registry.names("parser") == ["test-stripes"] and not registry.failures
    monkeypatch.setenv("SSGA_DISABLE_PLUGIN_AUTOLOAD", "1")
    assert get_plugin_manager().registry().names("parser") == []


def test_tracing_prints_hook_calls(fake_entry_points, monkeypatch, capsys):
    fake_entry_points(FakeEntryPoint("a", plugin_with(StripesParser)))
    monkeypatch.setenv("SSGA_TRACE_PLUGINS", "1")
    get_plugin_manager().registry()
    assert "ssga_register_parsers" in capsys.readouterr().err


def test_registry_creates_validated_instances(stand_in_registry):
    parser = stand_in_registry.create("parser", "test-stripes", stripes=3)
    assert parser.config.stripes == 3
    with pytest.raises(Exception, match="greater than or equal to 1"):
        stand_in_registry.create("parser", "test-stripes", stripes=0)


def test_no_module_imports_pluggy_but_the_core():
    # Plugins import hookimpl from ssga_core, so pluggy stays an implementation detail.
    for path in [*REPO.glob("plugins/*/*/src/**/*.py"), *REPO.glob("examples/*/src/**/*.py")]:
        assert "import pluggy" not in path.read_text(), path


def test_throwaway_plugin_modules_load_from_the_environment(tmp_path, monkeypatch, fake_entry_points):
    (tmp_path / "my_parser.py").write_text(
        "from ssga_core import hookimpl\n"
        "from ssga_core.testing.stages import StripesParser\n"
        "class Mine(StripesParser):\n    name = 'mine'\n"
        "@hookimpl\ndef ssga_register_parsers():\n    return [Mine]\n"
    )
    fake_entry_points()
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("SSGA_PLUGIN_MODULES", "my_parser, not_there")
    registry = get_plugin_manager().registry()
    assert registry.entry("parser", "mine").plugin.distribution == "(SSGA_PLUGIN_MODULES)"
    (failure,) = registry.failures
    assert "cannot import not_there: ModuleNotFoundError" in str(failure)
