"""Seeded procedural homes as an ssga workspace.

:func:`~ssga_workspace_procedural.generator.generate_home` builds a furnished,
textured, semantically labelled multi-room home from a seed;
:func:`~ssga_workspace_procedural.export.export_glb` writes it for Habitat-Sim or any
glTF viewer; the ``procedural`` workspace source (:mod:`.plugin`) renders it.

The public names are imported on first use, so that loading the plugin module (as
every ``ssga`` command does) does not import trimesh and scikit-image.
"""

from __future__ import annotations

from ssga_core import lazy_exports

_EXPORTS = {
    "CATEGORIES": "ssga_workspace_procedural.categories",
    "semantic_id": "ssga_workspace_procedural.categories",
    "export_glb": "ssga_workspace_procedural.export",
    "Home": "ssga_workspace_procedural.home",
    "HomeConfig": "ssga_workspace_procedural.home",
    "HomeObject": "ssga_workspace_procedural.home",
    "generate_home": "ssga_workspace_procedural.generator",
}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_exports(__name__, _EXPORTS)
