"""Bag-of-words node features over local features (paper §3.1.2), shared by every local descriptor.

The paper says of its Patch-NetVLAD (PNV) node features only this: the local features
of a region are "aggregated into a bag-of-words (BoW) histogram", the "BoW uses a
prototype dictionary of size k = 100, reciprocal rank (RR)-weighted (Cormack et al.,
2009), and a naive Bayes nearest-neighbor (NBNN) (Tommasi and Caputo, 2013) similarity
measure". This module is our reading of that sentence, written once so that every
local descriptor (dense SIFT, Patch-NetVLAD, ...) reuses it unchanged.

Reading
-------

* **Prototype dictionary.** k-means (k-means++ init, seeded) over the training views'
  local features gives ``k`` words; each word keeps up to ``prototypes`` of its member
  descriptors, drawn at random, as its *prototype set*.
* **NBNN similarity.** NBNN compares a feature with a class by the distance to the
  class's *nearest* stored descriptor, not to a class mean (Boiman et al., 2008;
  Tommasi and Caputo, 2013). Here the classes are the words: a feature's distance to
  word ``w`` is its squared Euclidean distance to the nearest prototype of ``w``. With
  ``similarity = "centroid"`` it is the distance to the word's centroid instead (the
  usual soft-assignment BoW, kept for comparison; ``prototypes = 1`` is not the same:
  it keeps one random member, not the mean).
* **Reciprocal-rank weighting.** Each feature ranks the ``k`` words by that distance
  (rank 1 = nearest; ties go to the lower word index) and votes ``1 / (c + rank)`` for
  each, or only for its ``top_n`` nearest words (``c = 0``: the plain reciprocal rank;
  Cormack et al. fuse with ``c = 60``). A feature's code is this ``(k,)`` vote vector:
  robust soft assignment, which needs no distance scale and is the same whatever the
  descriptor's units.
* **Histogram.** A node's feature is the sum of its member features' codes, normalised
  (``norm``): L2 by default, so that a node's feature does not grow with its number of
  features (a whole image holds 144, a small part a handful) and dot products between
  nodes are cosine similarities. A node with no feature gets zeros.

Defaults (measured with dense SIFT: how stable a region's node feature is between two
views of it; table and script in the README of ``ssga-descriptor-dense-sift``): NBNN
(clearly more stable than centroids), 64 prototypes per word (stable up to about 64,
flat beyond), votes for all ``k`` words with ``c = 0`` (``top_n >= 10`` is the same;
fewer, or a large ``c``, is worse), L2 norm (no norm is much worse), k-means++ with 20
Lloyd iterations (within 0.1 % of the inertia of 25). Re-check ``prototypes`` for a
new descriptor: encoding costs grow linearly with it.

For descriptor authors
----------------------

Subclass :class:`BoWDescriptor` and write only ``_extract`` (raw local features at
pixel positions). Give your config a ``bow: BoWConfig`` field (subclass
:class:`BoWDescriptorConfig`). The base class fits the dictionary on the training
views' features in :meth:`BoWDescriptor.fit`, encodes and pools in ``_pool``, and its
``dim`` is ``bow.k``. A Patch-NetVLAD plugin returns its 144 PCA-reduced patch
features with their image-space centres from ``_extract`` and is done; there is
nothing descriptor-specific in the BoW step besides the Euclidean distance, so give it
features for which Euclidean distance is meaningful (L2-normalised PNV or RootSIFT are).
Fitted dictionaries are plain arrays (:meth:`BagOfWords.state_dict`), to cache on disk.
Colour comes with the base class (``colour > 0`` in the config, :mod:`ssga_bench.colour`):
override :meth:`BoWDescriptor.colour_window` if your features describe a square of another
size than a tenth of the view's side.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from ssga_bench.colour import COLOUR_DIM, colour_histograms
from ssga_bench.kmeans import BLOCK, as_descriptor_matrix, kmeans
from ssga_bench.seeds import stream
from ssga_core.data import LocalFeatures, View
from ssga_core.errors import InputError, SsgaError
from ssga_core.ranking import ranks
from ssga_core.stages import LocalDescriptor, LocalDescriptorConfig, StageConfig

RECENT_CODES = 32
"""Codes each process remembers, by dictionary and features. Every variant with S fits its
dictionary on the same views, so they share it; scoring a chunk of query views view by
view through every variant (:func:`ssga_bench.experiment.score_chunk`) then encodes each
view's features once, not once per variant (encoding is most of the query path's work)."""
_recent_codes: OrderedDict[tuple[bytes, bytes], np.ndarray] = OrderedDict()


class NotFittedError(SsgaError, RuntimeError):
    """A bag-of-words dictionary was used before it was fitted."""


class BoWConfig(StageConfig):
    """How local features become bag-of-words node features (see :mod:`ssga_bench.bow`)."""

    k: int = Field(default=100, ge=2, le=4096, description="Dictionary size: the number of visual words (paper: 100).")
    similarity: Literal["nbnn", "centroid"] = Field(
        default="nbnn",
        description="Distance of a feature to a word: to the word's nearest prototype (NBNN) or to its centroid.",
    )
    prototypes: int = Field(
        default=64, ge=1, le=1024, description="Member descriptors each word keeps as its prototype set (used by NBNN)."
    )
    top_n: int | None = Field(
        default=None, ge=1, description="A feature votes for its top_n nearest words only; None: for all k."
    )
    rr_offset: float = Field(
        default=0.0, ge=0.0, description="c in the vote 1 / (c + rank): 0 is the plain reciprocal rank, Cormack et al. use 60."
    )
    norm: Literal["l2", "l1", "none"] = Field(default="l2", description="Normalisation of a node's summed votes.")
    init: Literal["k-means++", "random"] = Field(default="k-means++", description="k-means initialisation.")
    iterations: int = Field(default=20, ge=1, le=1000, description="Most k-means (Lloyd) iterations; stops early once stable.")
    max_train: int = Field(
        default=200_000, ge=1, description="Most training descriptors k-means sees; more are subsampled (seeded)."
    )
    seed: int = Field(default=0, description="Seed of the k-means init, the subsampling and the prototype draw.")

    @model_validator(mode="after")
    def _top_n_within_k(self) -> BoWConfig:
        if self.top_n is not None and self.top_n > self.k:
            raise ValueError(f"top_n ({self.top_n}) cannot exceed k ({self.k})")
        return self


# --------------------------------------------------------------------------- votes


def reciprocal_rank_votes(distances: np.ndarray, top_n: int | None = None, offset: float = 0.0) -> np.ndarray:
    """``(M, k)`` votes ``1 / (offset + rank)`` of each row's words ranked by ``distances`` (rank 1 = nearest).

    Ties go to the lower word index (:func:`ssga_core.ranking.ranks`). With ``top_n``, only
    a row's ``top_n`` nearest words get a vote; the others get 0.
    """
    distances = np.asarray(distances, dtype=np.float32)
    r = ranks(-distances, axis=1)
    votes = (1.0 / (offset + r)).astype(np.float32)
    if top_n is not None:
        votes[r > top_n] = 0.0
    return votes


def normalise_rows(x: np.ndarray, norm: Literal["l2", "l1", "none"]) -> np.ndarray:
    """Rows scaled to unit L2 or L1 norm (all-zero rows stay zero); ``"none"`` returns ``x``."""
    if norm == "none":
        return x
    n = np.linalg.norm(x, axis=1) if norm == "l2" else np.abs(x).sum(1)
    return np.divide(x, n[:, None], out=np.zeros_like(x), where=n[:, None] > 0)


def pool_rows(rows: np.ndarray, members: Sequence[np.ndarray], norm: Literal["l2", "l1", "none"]) -> np.ndarray:
    """``(N, D)`` float32: each node's summed member ``rows`` (``(M, D)``), normalised; zeros for an empty node."""
    out = np.zeros((len(members), rows.shape[1]), dtype=np.float32)
    for i, idx in enumerate(members):
        idx = np.asarray(idx, dtype=np.intp)
        if idx.size:
            out[i] = rows[idx].sum(axis=0)
    return normalise_rows(out, norm)


def grid_cells(positions: np.ndarray, members: np.ndarray, g: int) -> list[np.ndarray]:
    """``members`` split by the cell of a ``g`` x ``g`` grid laid on their positions' bounding box
    (row-major: ``u`` across, ``v`` down); a cell may be empty, and a feature with no position
    (one a synthesizer's point map lost) is in none."""
    members = np.asarray(members, dtype=np.intp)
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 2)[members]
    placed = np.isfinite(p).all(axis=1)
    members, p = members[placed], p[placed]
    if members.size == 0:
        return [members] * g**2
    low, span = p.min(axis=0), np.ptp(p, axis=0)
    # A feature on the box's far edge belongs to the last cell; a box of no extent is one cell.
    at = np.minimum((g * (p - low) / np.where(span > 0, span, 1.0)).astype(np.intp), g - 1)
    cell = at[:, 1] * g + at[:, 0]
    return [members[cell == c] for c in range(g**2)]


# --------------------------------------------------------------------------- dictionary


class BagOfWords:
    """A prototype dictionary: fit on training descriptors, encode features, pool them into nodes.

    Example::

        bow = BagOfWords(BoWConfig(k=100)).fit(train)       # train: (N, D)
        codes = bow.encode(features.descriptors)             # (M, k) RR votes
        nodes = bow.pool(codes, [np.arange(M), part_1, ...])  # (N_nodes, k)
    """

    def __init__(self, config: BoWConfig | None = None) -> None:
        self.config = config or BoWConfig()
        self.centroids: np.ndarray | None = None
        """``(k, D)`` float32 word centroids, once fitted."""
        self.prototypes: np.ndarray | None = None
        """``(k, m, D)`` float32 prototype sets (a word with fewer than ``m`` members repeats them)."""
        self._cache: tuple[np.ndarray, np.ndarray] | None = None
        self._fingerprint: bytes | None = None

    def __repr__(self) -> str:
        state = f"{self.centroids.shape[1]}-d" if self.centroids is not None else "unfitted"
        return f"BagOfWords({state}, {self.config!r})"

    @property
    def fitted(self) -> bool:
        return self.centroids is not None

    @property
    def dim(self) -> int:
        """Length of a code and of a node feature: ``k``."""
        return self.config.k

    def fit(self, descriptors: np.ndarray) -> BagOfWords:
        """Learn the words from training descriptors ``(N, D)``; returns ``self``.

        Raises:
            InputError: fewer than ``k`` descriptors (the dictionary would have unused
                words; lower ``k`` or give more training views), or non-finite values.
        """
        cfg = self.config
        x = as_descriptor_matrix("BagOfWords.fit", descriptors)
        if len(x) < cfg.k:
            raise InputError(
                f"bag of words: k = {cfg.k} words need at least {cfg.k} training descriptors, got {len(x)}; "
                "lower bow.k or fit on more views"
            )
        rng = stream(cfg.seed, "fitting")
        if len(x) > cfg.max_train:
            x = x[np.sort(rng.choice(len(x), cfg.max_train, replace=False))]
        centroids, labels = kmeans(x, cfg.k, iterations=cfg.iterations, init=cfg.init, rng=rng)
        self.centroids = centroids
        self.prototypes = _draw_prototypes(x, labels, centroids, cfg.prototypes, rng)
        self._cache = self._fingerprint = None
        return self

    def distances(self, descriptors: np.ndarray) -> np.ndarray:
        """``(M, k)`` squared distance of each descriptor to each word (NBNN or centroid, per config)."""
        centroids, _ = self._require_fitted()
        x = as_descriptor_matrix("BagOfWords.encode", descriptors, centroids.shape[1])
        minus_2p, p2 = self._targets()
        m = len(p2) // self.dim
        out = np.empty((len(x), self.dim), dtype=np.float32)
        step = max(1, BLOCK // len(p2))
        for s in range(0, len(x), step):
            d = x[s : s + step] @ minus_2p
            d += p2  # |x|^2 does not change which prototype is nearest: added after the minimum
            out[s : s + step] = d.reshape(len(d), m, self.dim).min(axis=1) if m > 1 else d
        out += (x * x).sum(1)[:, None]
        return np.maximum(out, 0.0, out=out)

    def _targets(self) -> tuple[np.ndarray, np.ndarray]:
        """What :meth:`distances` compares with, cached: ``-2 P^T`` ``(D, m k)`` and ``|P|^2`` ``(m k,)``.

        ``P`` is the centroids (``m = 1``) or the prototype sets, prototype-major (row
        ``j k + w`` is prototype ``j`` of word ``w``), so that the minimum over a word's
        prototypes reduces a middle axis, which numpy vectorises.
        """
        if self._cache is None:
            centroids, prototypes = self._require_fitted()
            if self.config.similarity == "centroid":
                p = centroids
            else:
                p = prototypes.transpose(1, 0, 2).reshape(-1, centroids.shape[1])
            self._cache = (np.ascontiguousarray(-2.0 * p.T), (p * p).sum(1))
        return self._cache

    def encode(self, descriptors: np.ndarray) -> np.ndarray:
        """``(M, k)`` float32 reciprocal-rank vote vector of each descriptor ``(M, D)``."""
        if len(descriptors) == 0:
            self._require_fitted()
            return np.zeros((0, self.dim), dtype=np.float32)
        centroids, _ = self._require_fitted()
        x = as_descriptor_matrix("BagOfWords.encode", descriptors, centroids.shape[1])
        key = (self.fingerprint(), hashlib.blake2b(x.data, digest_size=16).digest() + str(x.shape).encode())
        codes = _recent_codes.get(key)
        if codes is None:
            codes = reciprocal_rank_votes(self.distances(x), self.config.top_n, self.config.rr_offset)
            codes.flags.writeable = False  # shared by every caller with the same dictionary
            _recent_codes[key] = codes
            while len(_recent_codes) > RECENT_CODES:
                _recent_codes.popitem(last=False)
        _recent_codes.move_to_end(key)
        return codes

    def fingerprint(self) -> bytes:
        """A digest of the fitted dictionary and of what encoding depends on in the config."""
        if self._fingerprint is None:
            centroids, prototypes = self._require_fitted()
            h = hashlib.blake2b(digest_size=16)
            h.update(self.config.model_dump_json().encode())
            for a in (centroids, prototypes):
                h.update(str(a.shape).encode())
                h.update(np.ascontiguousarray(a).data)
            self._fingerprint = h.digest()
        return self._fingerprint

    def pool(self, codes: np.ndarray, members: Sequence[np.ndarray]) -> np.ndarray:
        """``(N, k)`` node features: each node's summed member codes, normalised; zeros for an empty node.

        Args:
            codes: ``(M, k)`` from :meth:`encode`.
            members: for each node, the indices into ``codes`` of its features.
        """
        codes = np.asarray(codes, dtype=np.float32)
        if codes.ndim != 2 or codes.shape[1] != self.dim:
            raise InputError(f"BagOfWords.pool: expected (M, {self.dim}) codes, got shape {codes.shape}")
        return pool_rows(codes, members, self.config.norm)

    def state_dict(self) -> dict[str, np.ndarray]:
        """The fitted dictionary as plain arrays (``centroids``, ``prototypes``), e.g. for ``np.savez``."""
        centroids, prototypes = self._require_fitted()
        return {"centroids": centroids.copy(), "prototypes": prototypes.copy()}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore a dictionary saved by :meth:`state_dict`; its shapes must match this config."""
        missing = {"centroids", "prototypes"} - set(state)
        if missing:
            raise InputError(f"bag of words state: missing {', '.join(sorted(missing))}")
        centroids = np.asarray(state["centroids"], dtype=np.float32)
        prototypes = np.asarray(state["prototypes"], dtype=np.float32)
        k, m = self.config.k, self.config.prototypes
        if centroids.ndim != 2 or centroids.shape[0] != k:
            raise InputError(f"bag of words state: centroids of shape {centroids.shape}, expected ({k}, D) for k = {k}")
        if prototypes.shape != (k, m, centroids.shape[1]):
            raise InputError(
                f"bag of words state: prototypes of shape {prototypes.shape}, expected {(k, m, centroids.shape[1])} "
                f"for k = {k}, prototypes = {m}"
            )
        self.centroids, self.prototypes = centroids.copy(), prototypes.copy()
        self._cache = self._fingerprint = None

    def _require_fitted(self) -> tuple[np.ndarray, np.ndarray]:
        if self.centroids is None or self.prototypes is None:
            raise NotFittedError("bag of words: the dictionary is not fitted; call fit() on training descriptors first")
        return self.centroids, self.prototypes


def _draw_prototypes(x: np.ndarray, labels: np.ndarray, centroids: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """Up to ``m`` random members per word, repeated to ``m``; the centroid for a word with none."""
    k, dim = centroids.shape
    perm = rng.permutation(len(x))
    order = perm[np.argsort(labels[perm], kind="stable")]  # grouped by word, random within a word
    counts = np.bincount(labels, minlength=k)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.empty((k, m, dim), dtype=np.float32)
    for w in range(k):
        if counts[w] == 0:
            out[w] = centroids[w]
        else:
            chosen = order[starts[w] : starts[w] + min(m, counts[w])]
            out[w] = x[np.resize(chosen, m)]
    return out


# --------------------------------------------------------------------------- descriptor base


class BoWDescriptorConfig(LocalDescriptorConfig):
    """Base config of a :class:`BoWDescriptor`: subclass it and add the descriptor's own fields."""

    bow: BoWConfig = Field(default=BoWConfig(), description="Bag-of-words dictionary and node-feature pooling.")
    colour: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="Share of a node's similarity given to colour: each local feature also keeps the colour histogram of "
        "a window around it (CIELAB, 4 x 4 x 4 bins), a node pools its features' into one, and two nodes' cosine is "
        "(1 - colour) times their words' plus colour times their colours'. 0: the words alone.",
    )
    pyramid: int = Field(
        default=1,
        ge=1,
        le=4,
        description="Cells per side of a spatial pyramid: 1, none; G > 1, a node's feature is its pooled words (and "
        "colours) beside the same pooled over each cell of a G x G grid laid on its features' bounding box, so that "
        "two nodes' cosine also asks where in them their words stand (docs/experiments.md, 'Words in place').",
    )
    pyramid_share: float = Field(
        default=0.5,
        gt=0.0,
        lt=1.0,
        description="With pyramid > 1, the share of a node's similarity given to its grid's cells (split equally among them).",
    )

    added_since: ClassVar[frozenset[str]] = frozenset({"pyramid", "pyramid_share"})


class BoWDescriptor(LocalDescriptor):
    """A local descriptor whose node features are bag-of-words histograms of its local features.

    A subclass implements only ``_extract`` (raw local features at pixel positions) and
    gives a ``Config`` with a ``bow: BoWConfig`` field (a :class:`BoWDescriptorConfig`).
    :meth:`fit` must run before pooling; ``dim`` is ``bow.k``.

    With ``colour > 0`` every local feature carries, after its own columns, the colour
    histogram of the :meth:`colour_window` around it (:mod:`ssga_bench.colour`); the
    dictionary sees the descriptor's own columns alone, a node's feature is its words
    (times ``sqrt(1 - colour)``) beside its colours (times ``sqrt(colour)``), both at unit
    length, and ``dim`` is ``bow.k + COLOUR_DIM``.
    """

    Config: ClassVar[type[StageConfig]] = BoWDescriptorConfig

    def __init__(self, config: StageConfig | None = None) -> None:
        super().__init__(config)
        bow_config = getattr(self.config, "bow", None)
        if not isinstance(bow_config, BoWConfig):
            raise TypeError(f"{type(self).__name__}.Config needs a `bow: BoWConfig` field (subclass BoWDescriptorConfig)")
        self.bow = BagOfWords(bow_config)

    @property
    def dim(self) -> int:
        return (self.bow.dim + (COLOUR_DIM if self._colour > 0 else 0)) * (1 + self._pyramid**2)

    @property
    def _pyramid(self) -> int:
        """Cells per side of the spatial pyramid, 0 for none."""
        g = int(getattr(self.config, "pyramid", 1))
        return g if g > 1 else 0

    @property
    def _colour(self) -> float:
        return float(getattr(self.config, "colour", 0.0))

    def extract(self, view: View) -> LocalFeatures:
        return self._with_colour(view, super().extract(view))

    def extract_many(self, views: Sequence[View]) -> list[LocalFeatures]:
        return [self._with_colour(view, f) for view, f in zip(views, super().extract_many(views))]

    def colour_window(self, view: View) -> int:
        """Side in pixels of the square around a local feature whose colours ``colour > 0``
        keeps: a tenth of the view's side (``sqrt(H W) / 10``, 26 px at 256 x 256, a little more
        than the 16 px between the features of a 12 x 12 grid, so that a part's colour is its
        own and not its neighbours'). A descriptor that knows what its features cover overrides it."""
        h, w = view.camera.shape
        return max(round(0.1 * (h * w) ** 0.5), 1)

    def _with_colour(self, view: View, features: LocalFeatures) -> LocalFeatures:
        if self._colour <= 0:
            return features
        colours = colour_histograms(view.rgb, features.positions, self.colour_window(view))
        return LocalFeatures(positions=features.positions, descriptors=np.concatenate([features.descriptors, colours], axis=1))

    def fit(self, views: Sequence[View], labels: Sequence[int] | None = None) -> None:
        """Fit the dictionary on the local features of ``views`` (at most ``bow.max_train``, evenly per view).

        The dictionary is unsupervised: ``labels`` (the views' place classes) are not used.
        """
        try:
            self.bow.fit(self.training_descriptors(views))
        except InputError as exc:
            raise InputError(f"descriptor {self.name!r}: {exc}") from None

    def training_descriptors(self, views: Sequence[View]) -> np.ndarray:
        """The raw local features of ``views`` that :meth:`fit` learns from, ``(N, D)``.

        To bound memory with many views, each view contributes at most
        ``ceil(max_train / len(views))`` of its features (a seeded random subset).
        """
        views = list(views)
        if not views:
            return np.zeros((0, 0), dtype=np.float32)
        cfg = self.bow.config
        per_view = -(-cfg.max_train // len(views))
        rng = stream(cfg.seed, "fitting")
        chunks = []
        for view in views:
            d = super().extract(view).descriptors  # the descriptor's own columns: no colour to compute and drop
            if len(d) > per_view:
                d = d[np.sort(rng.choice(len(d), per_view, replace=False))]
            chunks.append(d)
        return np.concatenate(chunks, axis=0)

    def _pool(self, features: LocalFeatures, members: Sequence[np.ndarray]) -> np.ndarray:
        if not self.bow.fitted:
            raise NotFittedError(
                f"descriptor {self.name!r} is not fitted: call fit(training views) to learn its bag-of-words dictionary before pooling"
            )
        codes = self.bow.encode(self._words(features.descriptors))
        nodes = self._pool_codes(codes, features.descriptors, members)
        g = self._pyramid
        if not g:
            return nodes
        cells = zip(*(grid_cells(features.positions, idx, g) for idx in members))  # per cell, its share of every node
        share = float(getattr(self.config, "pyramid_share", 0.5))
        # Each block at unit length (a non-empty one): the cosine of two nodes is (1 - share) times their own
        # plus share times the mean of their cells' (a cell empty in either adds nothing).
        return np.concatenate(
            [math.sqrt(1 - share) * nodes] + [math.sqrt(share / g**2) * self._pool_codes(codes, features.descriptors, c) for c in cells],
            axis=1,
        )

    def _pool_codes(self, codes: np.ndarray, descriptors: np.ndarray, members: Sequence[np.ndarray]) -> np.ndarray:
        words = self.bow.pool(codes, members)
        share = self._colour
        if share <= 0:
            return words
        colours = pool_rows(descriptors[:, -COLOUR_DIM:], members, "l2")
        # Both halves at unit length, weighed so that the cosine of two nodes mixes the two cosines by `colour`.
        return np.concatenate([math.sqrt(1 - share) * words, math.sqrt(share) * colours], axis=1)

    def _words(self, descriptors: np.ndarray) -> np.ndarray:
        """The columns of the local features that the dictionary learns and encodes: the
        descriptor's own, without the colour histograms ``colour > 0`` appends."""
        return descriptors[:, :-COLOUR_DIM] if self._colour > 0 else descriptors

    def state_dict(self) -> dict[str, Any]:
        """The fitted dictionary (:meth:`BagOfWords.state_dict`)."""
        return self.bow.state_dict()

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore a dictionary saved by :meth:`state_dict` instead of fitting."""
        self.bow.load_state_dict(state)
