"""Which neighbouring source pixels lie on one surface.

Two neighbouring source pixels lie on one surface unless their inverse depths
differ by more than ``depth_edge`` (relative) *and* by that much more than a
neighbouring step does: a floor seen at a grazing angle changes depth fast from row to
row, but evenly (:func:`surface_links`).
"""

from __future__ import annotations

import numpy as np

LINKED_RIGHT, LINKED_DOWN, INTERIOR = 1, 2, 4
"""The bits of :func:`surface_links`: the pixel is on one surface with its right
neighbour, with its lower neighbour, and with all four."""
_LINKED = LINKED_RIGHT | LINKED_DOWN


def surface_links(depth: np.ndarray, depth_edge: float = 0.03, max_depth: float = np.inf) -> np.ndarray:
    """Which neighbours of each pixel lie on its surface (the module docstring says how that is decided).

    Args:
        depth: ``(H, W)`` planar depths (unknown: ``<= 0``, non-finite, or beyond
            ``max_depth``: linked to nothing).
        depth_edge: relative inverse-depth step, beyond the neighbouring steps, that
            separates two surfaces.
        max_depth: depths beyond this are unknown.

    Returns:
        ``(H, W)`` uint8 of the bits :data:`LINKED_RIGHT`, :data:`LINKED_DOWN` and
        :data:`INTERIOR`.
    """
    depth = np.asarray(depth, dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.float32(1.0) / depth
        inverse[~((depth > 0) & (depth <= max_depth))] = np.nan  # NaN compares false: no link
    right, down = _links_along(inverse, depth_edge, 1), _links_along(inverse, depth_edge, 0)
    interior = right & down
    interior[:, 1:] &= right[:, :-1]
    interior[1:] &= down[:-1]
    interior[:, 0] = interior[0] = False
    links = right.view(np.uint8) * np.uint8(LINKED_RIGHT)
    links |= down.view(np.uint8) * np.uint8(LINKED_DOWN)
    links |= interior.view(np.uint8) * np.uint8(INTERIOR)
    return links


def _links_along(inverse: np.ndarray, depth_edge: float, axis: int) -> np.ndarray:
    """``(H, W)`` bool: whether a pixel is on one surface with its next neighbour along ``axis``."""
    head = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
    tail = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
    step = np.diff(inverse, axis=axis)
    allowed = np.maximum(inverse[tail], inverse[head])  # relative to the nearer of the two
    allowed *= np.float32(depth_edge)
    # Inverse depth is affine in the image on a plane: a step as large as the one
    # beside it is a ramp (a floor at a grazing angle), not an edge.
    bend = np.abs(np.diff(step, axis=axis))
    links = np.zeros(inverse.shape, dtype=bool)
    linked = links[head]
    with np.errstate(invalid="ignore"):
        np.less_equal(np.abs(step), allowed, out=linked)
        linked[tail] |= bend <= allowed[tail]
        linked[head] |= bend <= allowed[head]
    return links
