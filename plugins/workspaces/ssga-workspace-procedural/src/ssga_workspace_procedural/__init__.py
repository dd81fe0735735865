"""Seeded procedural homes as an ssga workspace.

:func:`~ssga_workspace_procedural.generator.generate_home` builds a furnished,
textured, semantically labelled multi-room home from a seed;
:func:`~ssga_workspace_procedural.export.export_glb` writes it for Habitat-Sim or any
glTF viewer; the ``procedural`` workspace source (:mod:`.plugin`) renders it.
"""

from __future__ import annotations

from ssga_workspace_procedural.categories import CATEGORIES, semantic_id
from ssga_workspace_procedural.export import export_glb
from ssga_workspace_procedural.generator import Home, HomeConfig, HomeObject, generate_home

__all__ = ["CATEGORIES", "Home", "HomeConfig", "HomeObject", "export_glb", "generate_home", "semantic_id"]
