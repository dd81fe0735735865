"""ssga: synthetic scene-graph augmentation for cross-view image localization; the minimal core.

This module is the core's public API: plugins import what they need from here (and
their tests from :mod:`ssga_core.testing`), never from the submodules, and never
import pluggy themselves::

    from ssga_core import Parser, Regions, StageConfig, View, hookimpl

Importing it loads numpy, pydantic and pluggy, and none of torch, OpenCV, shapely or
matplotlib.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

import pluggy

from ssga_core.config import resolve_stage
from ssga_core.data import Data, LocalFeatures, Regions, SceneGraph, Synthesis, View, box_pixels, boxes_from_labels
from ssga_core.errors import CheckpointError, ConfigError, InputError, MissingWeightsError, PluginError, SsgaError, VariantSyntaxError
from ssga_core.geometry import Camera, Pose
from ssga_core.kinds import KINDS, StageKind
from ssga_core.lazy import lazy_exports
from ssga_core.ranking import ranks, reciprocal_ranks
from ssga_core.stages import (
    Descriptor,
    Fuser,
    LocalDescriptor,
    LocalDescriptorConfig,
    Parser,
    RegionDescriptor,
    Stage,
    StageConfig,
    Synthesizer,
    WorkspaceSource,
)
from ssga_core.variants import Variant, parse_variant

try:
    __version__ = version("ssga-core")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

hookimpl = pluggy.HookimplMarker("ssga")
"""Marks a plugin's hook implementations: ``@hookimpl def ssga_register_parsers(): ...``."""

__all__ = [
    "Camera",
    "CheckpointError",
    "ConfigError",
    "Data",
    "Descriptor",
    "Fuser",
    "InputError",
    "KINDS",
    "LocalDescriptor",
    "LocalDescriptorConfig",
    "LocalFeatures",
    "MissingWeightsError",
    "Parser",
    "PluginError",
    "Pose",
    "RegionDescriptor",
    "Regions",
    "SceneGraph",
    "SsgaError",
    "Stage",
    "StageConfig",
    "StageKind",
    "Synthesis",
    "Synthesizer",
    "Variant",
    "VariantSyntaxError",
    "View",
    "WorkspaceSource",
    "box_pixels",
    "boxes_from_labels",
    "hookimpl",
    "lazy_exports",
    "parse_variant",
    "ranks",
    "reciprocal_ranks",
    "resolve_stage",
]
