"""ssga-bench: the method and the benchmark, on top of :mod:`ssga_core`.

The public API plugins and users import from (``from ssga_bench import FloorPlan``);
everything else is internal. Names load on first use, so importing the package (as
the ``ssga`` command does for its commands) does not import OpenCV, shapely or torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    # workspaces: what a workspace source plugin returns
    "FloorPlan": "workspace",
    "Workspace": "workspace",
    "CapturedWorkspace": "workspace",
    # the bag-of-words kit of local descriptors (paper §3.1.2)
    "BagOfWords": "bow",
    "BoWConfig": "bow",
    "BoWDescriptor": "bow",
    "BoWDescriptorConfig": "bow",
    "NotFittedError": "bow",
    # files: atomic writes, one-line read errors
    "OutputError": "io",
    "atomic_write_bytes": "io",
    "read_json": "io",
    "read_jsonl": "io",
    "write_json": "io",
    "read_png": "io",
    "write_png": "io",
    "depth_from_png16": "io",
    "depth_to_png16": "io",
    "ids_from_png16": "io",
    "ids_to_png16": "io",
    # experiments
    "ExperimentConfig": "config",
    "Experiment": "config",
    "TrainingConfig": "config",
    "load_experiment": "config",
    "validate_experiment": "config",
    "ProtocolConfig": "protocol",
    "Dataset": "dataset",
    "build_workspace": "dataset",
    "build_dataset": "dataset",
    "run_experiment": "experiment",
    "Report": "evaluation",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'ssga_bench' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"ssga_bench.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__

