"""Scene-graph assembly shared by every parser: node weights and edges by box proximity (paper §3.1.1, §3.2)."""

from __future__ import annotations

import numpy as np

from ssga_core.data import SceneGraph
from ssga_core.geometry import Camera

EDGE_GAP_PX = 20.0
"""Boxes closer than this (in pixels of a 256-pixel-wide image) are joined by an edge."""


def proximity_edges(boxes: np.ndarray, image_width: int, gap_px: float = EDGE_GAP_PX) -> np.ndarray:
    """Edges ``(E, 2)`` between boxes that overlap or whose nearest pixels are within the gap.

    Boxes are ``[u0, v0, u1, v1]`` in inclusive pixel-centre coordinates, so two
    regions with touching pixels are 1 px apart. The gap is ``gap_px`` at a width
    of 256 px and scales with ``image_width``.
    """
    boxes = np.asarray(boxes, dtype=np.float64)
    n = len(boxes)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    gap = gap_px * image_width / 256.0
    u0, v0, u1, v1 = (boxes[:, k] for k in range(4))
    dx = np.maximum(0.0, np.maximum(u0[None, :] - u1[:, None], u0[:, None] - u1[None, :]))
    dy = np.maximum(0.0, np.maximum(v0[None, :] - v1[:, None], v0[:, None] - v1[None, :]))
    close = np.hypot(dx, dy) <= gap
    i, j = np.nonzero(np.triu(close, k=1))
    return np.stack([i, j], axis=1).astype(np.int64)


def whole_image_box(camera: Camera) -> np.ndarray:
    return np.array([0.0, 0.0, camera.width - 1.0, camera.height - 1.0], dtype=np.float32)


def node_weights(num_parts: int) -> np.ndarray:
    """The whole image weighs 1 and each of the K parts ``1/K`` (paper §3.2)."""
    weights = np.full(1 + num_parts, 1.0 / max(num_parts, 1), dtype=np.float32)
    weights[SceneGraph.WHOLE_IMAGE] = 1.0
    return weights


DRAWN_BLOCKS = 16
"""The side of the grid a synthetic view's graph records where it was drawn on (``SceneGraph.drawn``):
16 x 16 blocks, 16 px at 256 x 256, finer than a SLICO part (64 of them in 256 x 256: 32 px across)."""


def assemble(
    camera: Camera,
    part_boxes: np.ndarray,
    features: np.ndarray,
    drawn: np.ndarray | None = None,
    part_origins: np.ndarray | None = None,
    part_categories: np.ndarray | None = None,
    part_category_scores: np.ndarray | None = None,
) -> SceneGraph:
    """The scene graph of a whole-image node (features row 0) and parts (rows 1..K); ``drawn``:
    where a synthetic view was drawn (:meth:`~ssga_core.View.drawn_blocks`); ``part_origins``:
    ``(K, 2)`` each part's (source view, region), -1 for none (``SceneGraph.part_origins``);
    ``part_categories``: ``(K,)`` each part's category (``Regions.categories``) and ``part_category_scores`` how sure
    the parser is of it (``Regions.scores``; kept only with the categories)."""
    boxes = np.concatenate([whole_image_box(camera)[None], np.asarray(part_boxes, dtype=np.float32).reshape(-1, 4)])
    origins = None
    if part_origins is not None and np.any(np.asarray(part_origins) >= 0):
        origins = np.concatenate([np.full((1, 2), -1, np.int32), np.asarray(part_origins, np.int32).reshape(-1, 2)])
    categories = category_scores = None
    if part_categories is not None:
        categories = np.concatenate([[-1], np.asarray(part_categories).reshape(-1)]).astype(np.int32)
        if part_category_scores is not None:
            category_scores = np.concatenate([[np.nan], np.asarray(part_category_scores).reshape(-1)]).astype(np.float32)
    return SceneGraph(
        boxes=boxes,
        features=np.asarray(features, dtype=np.float32),
        weights=node_weights(len(boxes) - 1),
        edges=proximity_edges(boxes, camera.width),
        drawn=drawn,
        part_origins=origins,
        categories=categories,
        category_scores=category_scores,
    )
