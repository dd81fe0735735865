"""The semantic categories of procedural homes and their stable ids.

The ids are part of the workspace's output (``View.semantic``) and of exported
``.semantic.json`` sidecars, so they never change meaning: new categories get new
ids at the end. ``0`` is not used, and ``-1`` is the views' "unknown".
"""

from __future__ import annotations

from ssga_core import InputError

CATEGORIES: dict[str, int] = {
    "wall": 1,
    "floor": 2,
    "ceiling": 3,
    "table": 4,
    "chair": 5,
    "sofa": 6,
    "bed": 7,
    "cabinet": 8,
    "shelf": 9,
    "plant": 10,
    "lamp": 11,
    "painting": 12,
    "rug": 13,
}
"""Category name -> semantic id (stable; documented in the package README)."""


def semantic_id(category: str) -> int:
    """The semantic id of ``category``; unknown names are an error rather than a silent ``-1``."""
    try:
        return CATEGORIES[category]
    except KeyError:
        raise InputError(f"unknown category {category!r}; known: {', '.join(CATEGORIES)}") from None
