"""The layers of docs/architecture.md hold: imports point down, plugins use only the public API.

Imports are read from the source (every ``import`` and ``from ... import``, at any depth,
except under ``if TYPE_CHECKING:``), so a lazy import inside a function counts too.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CORE = REPO / "ssga_core/src/ssga_core"
BENCH = REPO / "ssga_bench/src/ssga_bench"
PLUGIN_SOURCES = sorted(p for p in (REPO / "plugins").glob("*/*/src/*") if p.is_dir()) + sorted((REPO / "examples").glob("*/src/*"))

HEAVY = {"torch", "cv2", "shapely", "matplotlib", "skimage", "trimesh", "scipy"}
"""What a parser author must not have to install to use the core."""

PUBLIC = {"ssga_core", "ssga_core.cli", "ssga_bench"}
"""The modules plugins may import from: each package's public API (ssga_core.cli for commands), and the test kits."""
TEST_KITS = ("ssga_core.testing", "ssga_bench.testing")


def _imports(path: Path) -> list[str]:
    """Every module ``path`` imports, absolute, outside ``if TYPE_CHECKING:`` blocks."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    skipped: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skipped.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    found = []
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append(node.module)
    return found


def _sources(root: Path) -> list[Path]:
    return sorted(root.rglob("*.py"))


def _violations(roots: list[Path], allowed) -> list[str]:
    out = []
    for root in roots:
        for path in _sources(root):
            out += [f"{path.relative_to(REPO)} imports {m}" for m in _imports(path) if not allowed(m)]
    return out


def _top(module: str) -> str:
    return module.split(".")[0]


def test_the_core_imports_nothing_above_it_and_nothing_heavy():
    def allowed(module: str) -> bool:
        return _top(module) not in HEAVY and _top(module) != "ssga_bench" and not _top(module).startswith(("ssga_parser", "ssga_descriptor", "ssga_synthesizer", "ssga_fuser", "ssga_workspace"))

    assert _violations([CORE], allowed) == []


def test_the_benchmark_layer_imports_the_core_but_no_plugin():
    def allowed(module: str) -> bool:
        return not _top(module).startswith(("ssga_parser", "ssga_descriptor", "ssga_synthesizer", "ssga_fuser", "ssga_workspace"))

    assert _violations([BENCH], allowed) == []


@pytest.mark.parametrize("source", PLUGIN_SOURCES, ids=lambda p: p.name)
def test_plugins_use_only_the_public_api(source):
    def allowed(module: str) -> bool:
        if module in PUBLIC or module.startswith(TEST_KITS):
            return True
        return not module.startswith(("ssga_core", "ssga_bench"))  # anything else, its own package and other plugins included

    tests = source.parents[1] / "tests"
    assert _violations([source, tests] if tests.is_dir() else [source], allowed) == []


def test_the_public_api_names_exist():
    import ssga_bench
    import ssga_core

    for module in (ssga_core, ssga_bench):
        missing = [name for name in module.__all__ if not hasattr(module, name)]
        assert missing == [], f"{module.__name__}.__all__ names what it lacks: {missing}"


def test_importing_the_core_and_listing_variants_loads_nothing_heavy():
    # A fresh interpreter: this test process has imported everything already.
    code = (
        "import sys, ssga_core, ssga_core.cli, ssga_core.config, ssga_core.testing.contracts\n"
        "from ssga_core.variants import order_rows; order_rows()\n"
        f"print(sorted(m for m in {sorted(HEAVY)!r} if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_the_benchmark_layer_package_imports_lazily():
    code = "import sys, ssga_bench, ssga_bench.plugin\nprint(sorted(m for m in ('torch', 'cv2', 'shapely', 'matplotlib') if m in sys.modules))"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_the_core_and_the_benchmark_layer_name_no_plugin(ssga_installed_registry):
    # Defaults come from the packaged configs (ssga_bench/configs/*.toml), never from code.
    # "semantic" and "grid" are also a view channel and a plan key, which the layers do name.
    names = {entry.name for entry in ssga_installed_registry} - {"semantic", "grid"}
    named = []
    for path in _sources(CORE) + _sources(BENCH):
        if path.name == "testing.py" or "testing" in path.parts:
            continue  # the stand-ins have names of their own
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in names:
                named.append(f"{path.relative_to(REPO)}:{node.lineno} names {node.value!r}")
    assert names and named == []


TRAINING_COMMANDS = sorted(p for source in PLUGIN_SOURCES for p in (source / "train.py", source / "evaluate.py") if p.is_file())


@pytest.mark.parametrize("path", TRAINING_COMMANDS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_learned_plugins_train_and_evaluate_through_the_kit(path):
    """A plugin's training and evaluation commands are the kit's (`TrainingRun.command` with
    `training_main`, `evaluation_main`): none parses its own arguments or loops on its own."""
    source = path.read_text(encoding="utf-8")
    assert "ArgumentParser(" not in source, f"{path.relative_to(REPO)} parses its own command line"
    if path.name == "train.py":
        assert "(TrainingRun):" in source and "training_main(" in source, f"{path.relative_to(REPO)}: a Run on TrainingRun, main on training_main"
        assert "def run_training(" not in source, f"{path.relative_to(REPO)} drives the command itself (TrainingRun.command does)"
    else:
        assert "evaluation_main(" in source, f"{path.relative_to(REPO)}: main on evaluation_main"


def test_the_training_commands_are_found():
    assert {p.parent.name for p in TRAINING_COMMANDS} >= {"ssga_descriptor_pnv", "ssga_parser_cascade_seg", "ssga_synthesizer_midas_warp", "ssga_synthesizer_synsin", "ssga_descriptor_tinyseg"}
