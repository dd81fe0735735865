"""Loading the installed plugins does not import torch: listing and validating stay fast.

``ssga variants --list``, ``ssga plugins`` and ``ssga config validate`` import every
installed plugin's entry module; torch takes seconds to import, so a learned plugin
imports its network (and torch) inside the methods that build or run it. Each check
runs in a fresh interpreter: this test process has imported torch already.
"""

from __future__ import annotations

import importlib.metadata as metadata
import json
import os
import subprocess
import sys

import pytest

from ssga_core.plugins import ENTRY_POINT_GROUP

# Run in the child. Whether torch is in sys.modules decides; to say who imported it, a finder
# that only watches (the real finders still find torch) notes the chain of modules being
# executed when torch was first looked for.
_WATCH_TORCH = """
import importlib, json, sys

first_torch_import = []

class WatchTorch:
    def find_spec(self, name, path=None, target=None):
        if not first_torch_import and name == "torch":
            frame, chain = sys._getframe(1), []
            while frame is not None:
                if frame.f_code.co_name == "<module>":
                    chain.append(frame.f_globals.get("__name__", "?"))
                frame = frame.f_back
            first_torch_import.append(" -> ".join(reversed(chain)))
        return None

sys.meta_path.insert(0, WatchTorch())
"""

_IMPORT_ENTRY_MODULES = (
    _WATCH_TORCH
    + """
failures = {}
for module in sys.argv[1:]:
    try:
        importlib.import_module(module)
    except Exception as exc:
        failures[module] = f"{type(exc).__name__}: {exc}"
print(json.dumps({"torch": "torch" in sys.modules, "chain": (first_torch_import or ["not seen"])[0], "failures": failures}))
"""
)

_RUN_COMMAND = (
    _WATCH_TORCH
    + """
from ssga_core.cli import main

command, modules = json.loads(sys.argv[1]), json.loads(sys.argv[2])
sys.argv = ["ssga", *command]
try:
    main()
except SystemExit as exc:
    code = exc.code
else:
    code = 0
unloaded = [m for m in modules if m not in sys.modules]
result = {"code": code, "torch": "torch" in sys.modules, "chain": (first_torch_import or ["not seen"])[0], "unloaded": unloaded}
print("\\n" + json.dumps(result))
"""
)

ENTRY_MODULES = sorted({ep.module for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)})


def _child_env() -> dict[str, str]:
    """The environment with every installed plugin loading (whatever the caller's switches)."""
    switches = ("SSGA_DISABLE_PLUGIN_AUTOLOAD", "SSGA_PLUGINS", "SSGA_PLUGIN_MODULES", "SSGA_TRACE_PLUGINS")
    return {k: v for k, v in os.environ.items() if k not in switches}


def test_importing_every_plugins_entry_module_does_not_import_torch():
    # Learned plugins (they run torch networks) must be installed, or this proves little.
    assert {"ssga_descriptor_pnv.plugin", "ssga_descriptor_cnn_rrf.plugin", "ssga_synthesizer_synsin.plugin"} <= set(ENTRY_MODULES)
    result = subprocess.run(
        [sys.executable, "-c", _IMPORT_ENTRY_MODULES, *ENTRY_MODULES], capture_output=True, text=True, env=_child_env()
    )
    assert result.returncode == 0, result.stderr
    found = json.loads(result.stdout)
    assert found["failures"] == {}, "entry modules that cannot be imported"
    assert not found["torch"], f"an entry module imports torch when imported; the import chain: {found['chain']}"


@pytest.mark.parametrize(
    "command",
    [["variants", "--list"], ["plugins", "--json"], ["config", "validate", "paper"]],
    ids=["variants", "plugins", "config-validate"],
)
def test_listing_and_validating_load_every_plugin_but_not_torch(command):
    # The paper preset binds pnv and cnn-rrf: validating it validates their configs.
    result = subprocess.run(
        [sys.executable, "-c", _RUN_COMMAND, json.dumps(command), json.dumps(ENTRY_MODULES)],
        capture_output=True,
        text=True,
        env=_child_env(),
    )
    assert result.returncode == 0, result.stderr
    found = json.loads(result.stdout.splitlines()[-1])
    assert found["code"] == 0, result.stderr
    assert found["unloaded"] == [], "the command did not load these plugins, so it proves nothing about them"
    assert not found["torch"], f"`ssga {' '.join(command)}` imports torch; the import chain: {found['chain']}"
