"""The data that flows between stages: views, regions, local features, synthetic views, scene graphs.

All are frozen dataclasses over numpy arrays, validated on construction so a stage that
hands on a wrong-shaped array fails at the hand-over with a message naming the field,
not three stages later. Pixel and frame conventions are those of :mod:`ssga_core.geometry`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

import numpy as np

from ssga_core.errors import InputError
from ssga_core.geometry import Camera, Pose


class Data(str, Enum):
    """What a stage consumes or produces; used to check a bound variant before it runs."""

    RGB = "rgb"
    DEPTH = "depth"
    """Metric planar z-depth, per pixel."""
    SEMANTIC = "semantic"
    """Per-pixel semantic category and instance ids, as a semantic sensor gives."""
    REGIONS = "regions"
    LOCAL_FEATURES = "local-features"
    """Features at pixel positions, grouped into nodes afterwards; a synthesizer's point map can move them."""
    REGION_FEATURES = "region-features"
    """Features of given regions only (the image, or a region's pixels)."""
    POINT_MAP = "point-map"
    """Where each source pixel lands in a synthetic view."""

    def __str__(self) -> str:
        return self.value


VIEW_DATA = frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})
"""The kinds of data a :class:`View` can carry."""


def _check_array(name: str, a: object, shape: tuple[int, ...], dtypes: tuple[type, ...]) -> np.ndarray:
    if not isinstance(a, np.ndarray):
        raise InputError(f"{name}: expected a numpy array of shape {shape}, got {type(a).__name__}")
    if a.shape != shape or not any(np.issubdtype(a.dtype, d) for d in dtypes):
        want = "/".join(np.dtype(d).name if d not in (np.integer, np.floating) else d.__name__ for d in dtypes)
        raise InputError(f"{name}: expected shape {shape} of {want}, got shape {a.shape} of {a.dtype}")
    return a


@dataclass(frozen=True, eq=False)
class View:
    """One image of a place, with where it was taken from.

    Attributes:
        rgb: ``(H, W, 3)`` uint8.
        pose: the camera's pose.
        camera: intrinsics; ``(H, W)`` must match ``camera.shape``.
        depth: optional ``(H, W)`` float32 metric planar z-depth; ``<= 0`` or
            non-finite means unknown (holes in a synthetic view, sky, no return).
        semantic: optional ``(H, W)`` int32 semantic category ids; ``-1`` unknown.
        instance: optional ``(H, W)`` int32 instance ids; ``-1`` unknown.
        synthetic: whether the view was rendered by a synthesizer from another view.
    """

    rgb: np.ndarray
    pose: Pose
    camera: Camera = field(default_factory=Camera)
    depth: np.ndarray | None = None
    semantic: np.ndarray | None = None
    instance: np.ndarray | None = None
    synthetic: bool = False

    def __post_init__(self) -> None:
        h, w = self.camera.shape
        _check_array("View.rgb", self.rgb, (h, w, 3), (np.uint8,))
        if self.depth is not None:
            _check_array("View.depth", self.depth, (h, w), (np.floating,))
        for name in ("semantic", "instance"):
            ids = getattr(self, name)
            if ids is not None:
                _check_array(f"View.{name}", ids, (h, w), (np.integer,))

    @property
    def available(self) -> frozenset[Data]:
        """The :class:`Data` this view carries."""
        have = {Data.RGB}
        if self.depth is not None:
            have.add(Data.DEPTH)
        if self.semantic is not None or self.instance is not None:
            have.add(Data.SEMANTIC)
        return frozenset(have)

    def valid_depth(self) -> np.ndarray:
        """``(H, W)`` bool: where depth is known."""
        if self.depth is None:
            return np.zeros(self.camera.shape, dtype=bool)
        return np.isfinite(self.depth) & (self.depth > 0)

    def drawn_share(self, positions: np.ndarray, side: int) -> np.ndarray:
        """``(N,)`` float32: for a synthetic view, the share of the ``side x side`` pixels
        around each ``(u, v)`` position where its synthesizer drew a surface (known depth).

        1 everywhere for a real view, or a synthetic one without depth (nothing says where
        it drew). The square is clipped to the image; a position outside it gets 0.
        Pixels whose colour a synthesizer filled in (narrow cracks) carry no depth, so
        they count as holes: a wide enough square sees past them.
        """
        positions = np.asarray(positions, dtype=np.float32).reshape(-1, 2)
        if not self.synthetic or self.depth is None:
            return np.ones(len(positions), dtype=np.float32)
        h, w = self.camera.shape
        drawn = self._drawn_table()
        half = max(int(side), 1) // 2
        col = np.rint(np.nan_to_num(positions[:, 0], nan=-1e9)).clip(-1, w).astype(np.intp)
        row = np.rint(np.nan_to_num(positions[:, 1], nan=-1e9)).clip(-1, h).astype(np.intp)
        c0, c1 = (col - half).clip(0, w), (col + half + 1).clip(0, w)
        r0, r1 = (row - half).clip(0, h), (row + half + 1).clip(0, h)
        area = (r1 - r0) * (c1 - c0)
        count = drawn[r1, c1] - drawn[r0, c1] - drawn[r1, c0] + drawn[r0, c0]
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        return np.where(inside & (area > 0), count / np.maximum(area, 1), 0.0).astype(np.float32)

    def _drawn_table(self) -> np.ndarray:
        """``(H + 1, W + 1)``: a summed-area table of where depth is known, one row and column of zeros first."""
        h, w = self.camera.shape
        drawn = np.zeros((h + 1, w + 1), dtype=np.float64)
        drawn[1:, 1:] = self.valid_depth().cumsum(0).cumsum(1)
        return drawn

    def drawn_blocks(self, blocks: int) -> np.ndarray:
        """``(blocks, blocks)`` float32: for a synthetic view, the share of each block of an even
        ``blocks x blocks`` grid over the image where its synthesizer drew a surface (known depth);
        1 everywhere for a real view, or a synthetic one without depth (as :meth:`drawn_share`)."""
        if blocks < 1:
            raise InputError(f"View.drawn_blocks: blocks must be positive, got {blocks}")
        if not self.synthetic or self.depth is None:
            return np.ones((blocks, blocks), dtype=np.float32)
        h, w = self.camera.shape
        rows = np.linspace(0, h, blocks + 1).round().astype(np.intp)
        cols = np.linspace(0, w, blocks + 1).round().astype(np.intp)
        drawn = self._drawn_table()
        count = drawn[rows[1:, None], cols[None, 1:]] - drawn[rows[:-1, None], cols[None, 1:]]
        count -= drawn[rows[1:, None], cols[None, :-1]] - drawn[rows[:-1, None], cols[None, :-1]]
        area = np.diff(rows)[:, None] * np.diff(cols)[None, :]
        return (count / np.maximum(area, 1)).astype(np.float32)


def boxes_from_labels(labels: np.ndarray, count: int) -> np.ndarray:
    """``(count, 4)`` bounding boxes ``[u0, v0, u1, v1]`` (inclusive pixel centres) of each label.

    Labels with no pixel get NaN boxes. Marks the columns and rows each label occupies
    and takes the first and last of each: one pass over the pixels (about 0.5 ms at
    256 x 256, where ``np.minimum.at`` took 14).
    """
    h, w = labels.shape
    index = np.where(labels >= 0, labels, count)
    cols = np.zeros((count + 1, w), dtype=bool)
    cols[index, np.arange(w)[None, :]] = True
    rows = np.zeros((count + 1, h), dtype=bool)
    rows[index, np.arange(h)[:, None]] = True
    cols, rows = cols[:count], rows[:count]
    first_u, first_v = cols.argmax(axis=1), rows.argmax(axis=1)
    last_u, last_v = w - 1 - cols[:, ::-1].argmax(axis=1), h - 1 - rows[:, ::-1].argmax(axis=1)
    boxes = np.stack([first_u, first_v, last_u, last_v], axis=1).astype(np.float32)
    boxes[~cols.any(axis=1)] = np.nan
    return boxes


def box_pixels(image: np.ndarray, box: np.ndarray) -> np.ndarray:
    """The pixels of ``image`` (``(H, W, ...)``) inside ``box`` (``[u0, v0, u1, v1]``, inclusive pixel centres, as
    :attr:`Regions.boxes` has them), widened to at least 2 x 2 pixels and kept inside the image: a region's crop
    for a descriptor that describes boxes."""
    h, w = image.shape[:2]
    u0, v0 = (int(np.clip(np.floor(x), 0, n - 2)) for x, n in ((box[0], w), (box[1], h)))
    u1, v1 = (int(np.clip(np.ceil(x), lo + 1, n - 1)) for x, lo, n in ((box[2], u0, w), (box[3], v0, h)))
    return image[v0 : v1 + 1, u0 : u1 + 1]


@dataclass(frozen=True, eq=False)
class Regions:
    """The regions a parser cut an image into: scene-graph part nodes.

    A label map rather than one mask per region: it is what segmenters and
    superpixel methods produce, it costs one int per pixel whatever the count,
    and a synthesizer's point map warps it in one pass. Region ``k``'s mask is
    ``labels == k``; parsers whose regions overlap (boxes from a detector) assign
    each pixel to one region.

    Attributes:
        labels: ``(H, W)`` int32, the region of each pixel, ``-1`` for none.
        boxes: ``(K, 4)`` float32 ``[u0, v0, u1, v1]`` in pixel-centre coordinates,
            inclusive. By default the bounding box of the mask; a detector may give
            its own, and a synthesizer moves them with the point map.
        categories: optional ``(K,)`` int32 semantic category of each region.
        names: optional class name of each region (``K`` strings), for the people who
            look at a scene graph: a segmenter's or detector's vocabulary entry.
        scores: optional ``(K,)`` float32 confidence of each region (a detector's score, a
            segmenter's mean probability of the region's class).

    The optional per-region attributes travel with their regions wherever regions are
    selected, moved by a synthesizer or joined (``PER_REGION`` lists them, so each of
    those places carries them all without naming them).
    """

    PER_REGION: ClassVar[tuple[str, ...]] = ("categories", "names", "scores")

    labels: np.ndarray
    boxes: np.ndarray
    categories: np.ndarray | None = None
    names: tuple[str, ...] | None = None
    scores: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.labels, np.ndarray) or self.labels.ndim != 2:
            raise InputError(f"Regions.labels: expected an (H, W) int array, got {getattr(self.labels, 'shape', self.labels)!r}")
        _check_array("Regions.labels", self.labels, self.labels.shape, (np.integer,))
        k = len(self.boxes) if isinstance(self.boxes, np.ndarray) else -1
        _check_array("Regions.boxes", self.boxes, (k, 4), (np.floating,))
        if self.labels.size and self.labels.max(initial=-1) >= k:
            raise InputError(f"Regions.labels: label {int(self.labels.max())} has no box (there are {k} boxes)")
        if self.categories is not None:
            _check_array("Regions.categories", self.categories, (k,), (np.integer,))
        if self.names is not None and (not isinstance(self.names, tuple) or len(self.names) != k):
            raise InputError(f"Regions.names: expected a tuple of {k} strings, got {type(self.names).__name__} of {len(self.names)}")
        if self.scores is not None:
            _check_array("Regions.scores", self.scores, (k,), (np.floating,))

    @classmethod
    def from_labels(cls, labels: np.ndarray, categories: np.ndarray | None = None, scores: np.ndarray | None = None) -> Regions:
        """Regions from a label map, renumbering labels to ``0..K-1`` and dropping empty ones.

        ``categories`` and ``scores``, if given, are indexed by the *original* label values.
        """
        labels = np.asarray(labels)
        inside = labels >= 0
        top = int(labels.max(initial=-1))
        # Counting is O(pixels) where sorting is not; ids can be large (instance ids), so fall back.
        present = np.flatnonzero(np.bincount(labels[inside], minlength=top + 1)) if top < 1 << 20 else np.unique(labels[inside])
        lut = np.full(int(present.max(initial=-1)) + 2, -1, dtype=np.int32)
        lut[present] = np.arange(len(present), dtype=np.int32)
        dense = np.where(labels >= 0, lut[np.clip(labels, 0, None)], -1).astype(np.int32)
        cats = None if categories is None else np.asarray(categories, dtype=np.int32)[present]
        confidence = None if scores is None else np.asarray(scores, dtype=np.float32)[present]
        return cls(labels=dense, boxes=boxes_from_labels(dense, len(present)), categories=cats, scores=confidence)

    def __len__(self) -> int:
        return len(self.boxes)

    def mask(self, k: int) -> np.ndarray:
        return self.labels == k

    def centroids(self) -> np.ndarray:
        """``(K, 2)`` mean ``(u, v)`` of each region's pixels (NaN for empty ones)."""
        v, u = np.nonzero(self.labels >= 0)
        lab = self.labels[v, u]
        n = np.bincount(lab, minlength=len(self)).astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            cu = np.bincount(lab, weights=u, minlength=len(self)) / n
            cv = np.bincount(lab, weights=v, minlength=len(self)) / n
        return np.stack([cu, cv], axis=-1).astype(np.float32)

    def select(self, keep: np.ndarray) -> Regions:
        """The regions where ``keep`` (a ``(K,)`` bool) is true, renumbered in order."""
        keep = np.asarray(keep, dtype=bool)
        lut = np.full(len(self) + 1, -1, dtype=np.int32)
        lut[np.flatnonzero(keep)] = np.arange(int(keep.sum()), dtype=np.int32)
        labels = lut[np.where(self.labels >= 0, self.labels, len(self))]
        return Regions(labels=labels, boxes=self.boxes[keep], **_take(self.attributes(), np.flatnonzero(keep)))

    def merge(self, groups: np.ndarray) -> Regions:
        """The regions joined by group: ``groups`` (``(K,)`` int) is each region's new index,
        ``0..G-1`` with none left empty, or -1 to drop it.

        A group's box is the union of its members' boxes (a synthesizer's boxes are not the masks'
        own, so they are not recomputed); its optional attributes are its first member's.
        """
        groups = np.asarray(groups, dtype=np.int32)
        count = int(groups.max(initial=-1)) + 1
        kept = groups >= 0
        if set(groups[kept].tolist()) != set(range(count)):
            raise InputError(f"Regions.merge: groups must number 0..{count - 1} with none empty, got {groups.tolist()}")
        lut = np.append(groups, -1)
        labels = lut[np.where(self.labels >= 0, self.labels, len(self))]
        boxes = np.full((count, 4), np.nan, dtype=np.float32)
        with np.errstate(invalid="ignore"):
            np.fmin.at(boxes[:, :2], groups[kept], self.boxes[kept, :2])
            np.fmax.at(boxes[:, 2:], groups[kept], self.boxes[kept, 2:])
        first = np.array([np.flatnonzero(groups == g)[0] for g in range(count)], dtype=np.intp)
        return Regions(labels=labels, boxes=boxes, **_take(self.attributes(), first))

    def attributes(self) -> dict[str, np.ndarray | tuple[str, ...]]:
        """The optional per-region attributes this instance has (``PER_REGION`` names, present ones only)."""
        return {name: getattr(self, name) for name in self.PER_REGION if getattr(self, name) is not None}

    @classmethod
    def concatenate(cls, parts: Sequence[Regions], labels: np.ndarray) -> Regions:
        """Several parts' regions as one, in order, over a joined label map already offset to match.

        An optional attribute survives only where every part has it.
        """
        boxes = np.concatenate([r.boxes for r in parts]).astype(np.float32)
        joined: dict[str, np.ndarray | tuple[str, ...]] = {}
        for name in cls.PER_REGION:
            values = [getattr(r, name) for r in parts]
            if all(v is not None for v in values):
                joined[name] = sum(values, ()) if name == "names" else np.concatenate(values)
        return cls(labels=labels, boxes=boxes, **joined)


def _take(attributes: dict[str, np.ndarray | tuple[str, ...]], index: np.ndarray) -> dict[str, np.ndarray | tuple[str, ...]]:
    return {
        name: tuple(value[i] for i in index) if isinstance(value, tuple) else value[index]
        for name, value in attributes.items()
    }


@dataclass(frozen=True, eq=False)
class LocalFeatures:
    """Features at pixel positions (e.g. 144 dense SIFT or Patch-NetVLAD patches).

    Attributes:
        positions: ``(M, 2)`` float32 ``(u, v)`` of each feature's centre.
        descriptors: ``(M, D)`` float32.
    """

    positions: np.ndarray
    descriptors: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.positions) if isinstance(self.positions, np.ndarray) else -1
        _check_array("LocalFeatures.positions", self.positions, (m, 2), (np.floating,))
        d = self.descriptors.shape[1] if isinstance(self.descriptors, np.ndarray) and self.descriptors.ndim == 2 else -1
        _check_array("LocalFeatures.descriptors", self.descriptors, (m, d), (np.floating,))

    def __len__(self) -> int:
        return len(self.positions)

    def select(self, keep: np.ndarray) -> LocalFeatures:
        return LocalFeatures(positions=self.positions[keep], descriptors=self.descriptors[keep])


@dataclass(frozen=True, eq=False)
class Synthesis:
    """A synthetic view rendered from a source view, with the point map that made it.

    The point map is dense: for every *source* pixel, where it lands in the target
    image. It is what carries scene-graph node boxes (centroid and corners, paper
    §3.2) and local-feature positions from the real view into the synthetic one.

    Attributes:
        view: the synthetic view at the target pose (``synthetic=True``).
        target_uv: ``(H, W, 2)`` float32, each source pixel's position in the target
            image; NaN where the source depth is unknown or the point is behind the
            target camera. Positions outside the image are kept (box corners may be).
        visible: ``(H, W)`` bool, the source pixel lands inside the target image on
            the front-most surface there (within the synthesizer's depth tolerance, so
            several source pixels of one surface may share a target pixel).
    """

    view: View
    target_uv: np.ndarray
    visible: np.ndarray

    def __post_init__(self) -> None:
        h, w = self.view.camera.shape
        src = self.target_uv.shape[:2] if isinstance(self.target_uv, np.ndarray) else None
        if src is None or self.target_uv.ndim != 3:
            raise InputError(f"Synthesis.target_uv: expected an (H, W, 2) float array, got {src!r}")
        _check_array("Synthesis.target_uv", self.target_uv, (*src, 2), (np.floating,))
        _check_array("Synthesis.visible", self.visible, src, (np.bool_,))
        del h, w  # the source and target images may differ in size

    def map_points(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Carry source pixel positions ``(N, 2)`` into the target image.

        Each point takes the mapping of its nearest source pixel.

        Returns:
            ``(N, 2)`` target positions (NaN where unknown) and ``(N,)`` visibility.
        """
        sh, sw = self.visible.shape
        uv = np.asarray(uv, dtype=np.float32).reshape(-1, 2)
        col = np.clip(np.rint(uv[:, 0]), 0, sw - 1).astype(np.intp)
        row = np.clip(np.rint(uv[:, 1]), 0, sh - 1).astype(np.intp)
        return self.target_uv[row, col], self.visible[row, col]

    def warp_labels(self, labels: np.ndarray) -> np.ndarray:
        """Forward-splat a per-pixel int label map of the source into the target (``-1`` where nothing lands)."""
        th, tw = self.view.camera.shape
        out = np.full((th, tw), -1, dtype=np.int32)
        src = self.visible & (labels >= 0)
        tgt = np.rint(self.target_uv[src]).astype(np.intp)
        out[tgt[:, 1], tgt[:, 0]] = labels[src]
        return out


@dataclass(frozen=True, eq=False)
class SceneGraph:
    """A scene graph ready for the GCN.

    Node 0 is always the whole image (``WHOLE_IMAGE``); nodes ``1..K`` are parts.

    Attributes:
        boxes: ``(N, 4)`` float32 node boxes ``[u0, v0, u1, v1]`` in the image the
            graph describes (the synthetic one for a synthetic training graph).
        features: ``(N, F)`` float32 node features.
        weights: ``(N,)`` float32; the whole image 1, each of the K parts ``1/K``
            (paper §3.2). The GCN multiplies each node's feature by its weight.
        edges: ``(E, 2)`` int64 undirected edges ``i < j``.
        drawn: for the graph of a synthetic view, ``(B, B)`` float32: the share of each
            block of a ``B x B`` grid over its image that the synthesizer drew
            (:meth:`View.drawn_blocks`); None for a real view, all of which was seen.
            A pseudo-view is often half holes: a matcher can then judge a query's parts
            only against what the pseudo-view shows where they stand.
        part_origins: ``(N, 2)`` int32: which part of which real view each node is,
            ``(source, region)``: ``source`` indexes the real views the graph was built
            from (0 for a real view's own graph), ``region`` that view's parse; ``(-1, -1)``
            for the whole image and for parts parsed on a synthetic view. It follows a part
            through S, so the pseudo-views of one class show how one real part varies under
            synthesis. None where no node comes from a real view's parse.
        categories: ``(N,)`` int32: each node's semantic category as its parser named it
            (``Regions.categories``), -1 for the whole image; None where the parser names none
            (superpixels). A matcher can then pair a part only with parts of its own category.
        category_scores: ``(N,)`` float32: how sure the parser is of each node's category
            (``Regions.scores``: a segmenter's mean probability of the class over the part, a
            detector's score), NaN for the whole image; None where it gives none (ground truth).
            A matcher can then trust only the categories the parser is sure of.
    """

    WHOLE_IMAGE: ClassVar[int] = 0

    boxes: np.ndarray
    features: np.ndarray
    weights: np.ndarray
    edges: np.ndarray
    drawn: np.ndarray | None = None
    part_origins: np.ndarray | None = None
    categories: np.ndarray | None = None
    category_scores: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.boxes) if isinstance(self.boxes, np.ndarray) else -1
        if n < 1:
            raise InputError("SceneGraph: needs at least the whole-image node")
        _check_array("SceneGraph.boxes", self.boxes, (n, 4), (np.floating,))
        f = self.features.shape[1] if isinstance(self.features, np.ndarray) and self.features.ndim == 2 else -1
        _check_array("SceneGraph.features", self.features, (n, f), (np.floating,))
        _check_array("SceneGraph.weights", self.weights, (n,), (np.floating,))
        e = len(self.edges) if isinstance(self.edges, np.ndarray) else -1
        _check_array("SceneGraph.edges", self.edges, (e, 2), (np.integer,))
        if e and (self.edges.min() < 0 or self.edges.max() >= n or np.any(self.edges[:, 0] >= self.edges[:, 1])):
            raise InputError(f"SceneGraph.edges: expected pairs i < j of node indices below {n}")
        if self.drawn is not None:
            side = self.drawn.shape[0] if isinstance(self.drawn, np.ndarray) and self.drawn.ndim == 2 else -1
            _check_array("SceneGraph.drawn", self.drawn, (side, side), (np.floating,))
            if side < 1 or not np.all((self.drawn >= 0) & (self.drawn <= 1)):
                raise InputError("SceneGraph.drawn: expected a square grid of shares in [0, 1]")
        if self.part_origins is not None:
            _check_array("SceneGraph.part_origins", self.part_origins, (n, 2), (np.integer,))
            if np.any(self.part_origins[self.WHOLE_IMAGE] != -1) or np.any((self.part_origins < 0) & (self.part_origins[:, ::-1] >= 0)):
                raise InputError("SceneGraph.part_origins: expected (source, region) pairs, both >= 0 or both -1, and -1 for the whole image")
        if self.categories is not None:
            _check_array("SceneGraph.categories", self.categories, (n,), (np.integer,))
            if self.categories[self.WHOLE_IMAGE] != -1:
                raise InputError("SceneGraph.categories: expected -1 for the whole image, which has no category")
        if self.category_scores is not None:
            if self.categories is None:
                raise InputError("SceneGraph.category_scores: given without SceneGraph.categories, whose scores they are")
            _check_array("SceneGraph.category_scores", self.category_scores, (n,), (np.floating,))

    @property
    def num_nodes(self) -> int:
        return len(self.boxes)

    @property
    def num_parts(self) -> int:
        return self.num_nodes - 1
