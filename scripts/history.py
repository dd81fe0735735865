"""This repository's own code as it was at an earlier commit, for the scripts that measure a change against it."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent


def module_at(commit: str, path: str, name: str) -> ModuleType:
    """The Python file ``path`` (from the repository's root) as it was at ``commit``, imported as module ``name``."""
    source = subprocess.run(["git", "show", f"{commit}:{path}"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    spec = importlib.util.spec_from_loader(name, loader=None)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    exec(compile(source, f"{commit}:{Path(path).name}", "exec"), module.__dict__)  # noqa: S102 - this repository's own history
    return module
