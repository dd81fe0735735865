"""Public names that load on first use (PEP 562), for packages whose modules are heavy.

A plugin module is imported by every ``ssga`` command, to register its classes; if
its package's ``__init__`` imported trimesh or torch to re-export them, listing
variants would pay for it. Instead::

    __getattr__ = lazy_exports(__name__, {"MeshRenderer": "my_package.renderer"})
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, exports: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` importing ``exports[name]`` (a module path) the first time ``name`` is read."""

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)  # later reads skip this function
        return value

    return __getattr__
