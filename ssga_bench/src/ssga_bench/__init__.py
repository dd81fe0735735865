"""ssga-bench: the method and the benchmark, on top of :mod:`ssga_core`.

The public API plugins and users import from (``from ssga_bench import FloorPlan``);
everything else is internal. Names load on first use, so importing the package (as
the ``ssga`` command does for its commands) does not import OpenCV, shapely or torch.
"""

from __future__ import annotations

from ssga_core import lazy_exports

_EXPORTS = {
    # workspaces: what a workspace source plugin returns
    "FloorPlan": "ssga_bench.workspace",
    "Workspace": "ssga_bench.workspace",
    "CapturedWorkspace": "ssga_bench.workspace",
    "grid_polygons": "ssga_bench.workspace",
    # a floor plan of what views saw (their poses and depth)
    "FloorEvidence": "ssga_bench.seen_floor",
    "floor_plan_from_captures": "ssga_bench.seen_floor",
    # levelling a scan or a sequence: up to +z, the floor at z = 0
    "rotation_to_z": "ssga_bench.levelling",
    "lowest_level": "ssga_bench.levelling",
    "weighted_quantiles": "ssga_bench.levelling",
    # the bag-of-words kit of local descriptors (paper §3.1.2)
    "BagOfWords": "ssga_bench.bow",
    "BoWConfig": "ssga_bench.bow",
    "BoWDescriptor": "ssga_bench.bow",
    "BoWDescriptorConfig": "ssga_bench.bow",
    "NotFittedError": "ssga_bench.bow",
    "COLOUR_DIM": "ssga_bench.colour",
    "colour_histograms": "ssga_bench.colour",
    # learned (torch) stages: weights, device, strict checkpoint loading
    "Learned": "ssga_bench.learned",
    "LearnedConfig": "ssga_bench.learned",
    "RANDOM_WEIGHTS": "ssga_bench.learned",
    "RANDOM_SEED": "ssga_bench.learned",
    "weights_field": "ssga_bench.learned",
    "torch_threads": "ssga_bench.learned",
    "network_field": "ssga_bench.learned",
    "find_weights": "ssga_bench.learned",
    "load_checkpoint": "ssga_bench.learned",
    "load_strict": "ssga_bench.learned",
    "Layout": "ssga_bench.learned",
    "file_stamp": "ssga_bench.learned",
    "read_layout": "ssga_bench.learned",
    "meta_shapes": "ssga_bench.learned",
    "seeded": "ssga_bench.learned",
    "tensor_state": "ssga_bench.learned",
    "checkpoint_bytes": "ssga_bench.learned",
    "resolve_device": "ssga_bench.learned",
    "network_calls": "ssga_bench.learned",
    # the execution layer: what a plugin that starts its own processes needs
    "single_threaded_children": "ssga_bench.execution",
    # training commands of learned plugins: the staged resumable loop, provenance, export, CLI
    "TrainingRun": "ssga_bench.training",
    "training_log": "ssga_bench.training",
    "training_main": "ssga_bench.training",
    "training_provenance": "ssga_bench.training",
    "command_line": "ssga_bench.training",
    "export_checkpoint": "ssga_bench.training",
    "cosine_lr": "ssga_bench.training",
    "poly_lr": "ssga_bench.training",
    "photometric_jitter": "ssga_bench.training",
    "evaluation_main": "ssga_bench.training",
    # training views of homes, rendered once per home
    "ArrayRecord": "ssga_bench.training_data",
    "cached_homes": "ssga_bench.training_data",
    # how good a synthesis is, against the true render
    "QualityTally": "ssga_bench.synthesis_quality",
    "seen_mask": "ssga_bench.synthesis_quality",
    # files: atomic writes, one-line read errors
    "OutputError": "ssga_bench.io",
    "atomic_write_bytes": "ssga_bench.io",
    "read_json": "ssga_bench.io",
    "read_jsonl": "ssga_bench.io",
    "write_json": "ssga_bench.io",
    "read_png": "ssga_bench.io",
    "read_rgb": "ssga_bench.io",
    "fit_channel": "ssga_bench.io",
    "write_png": "ssga_bench.io",
    "depth_from_png16": "ssga_bench.io",
    "depth_to_png16": "ssga_bench.io",
    "ids_from_png16": "ssga_bench.io",
    "ids_to_png16": "ssga_bench.io",
    # experiments
    "ExperimentConfig": "ssga_bench.config",
    "Experiment": "ssga_bench.config",
    "TrainingConfig": "ssga_bench.config",
    "load_experiment": "ssga_bench.config",
    "validate_experiment": "ssga_bench.config",
    "ProtocolConfig": "ssga_bench.protocol",
    "Dataset": "ssga_bench.dataset",
    "build_workspace": "ssga_bench.dataset_build",
    "build_dataset": "ssga_bench.dataset_build",
    "run_experiment": "ssga_bench.experiment",
    "Report": "ssga_bench.evaluation",
}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
