"""ssga: synthetic scene-graph augmentation for cross-view image localization.

Plugins import what they need from here and never import pluggy themselves::

    from ssga_core import Parser, Regions, StageConfig, View, hookimpl
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

import pluggy

from ssga_core.data import Data, LocalFeatures, Regions, SceneGraph, Synthesis, View
from ssga_core.errors import CheckpointError, ConfigError, InputError, PluginError, SsgaError, VariantSyntaxError
from ssga_core.geometry import Camera, Pose
from ssga_core.stages import (
    Descriptor,
    Fuser,
    LocalDescriptor,
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
    "LocalDescriptor",
    "LocalFeatures",
    "Parser",
    "PluginError",
    "Pose",
    "RegionDescriptor",
    "Regions",
    "SceneGraph",
    "SsgaError",
    "Stage",
    "StageConfig",
    "Synthesis",
    "Synthesizer",
    "Variant",
    "VariantSyntaxError",
    "View",
    "WorkspaceSource",
    "hookimpl",
    "parse_variant",
]
