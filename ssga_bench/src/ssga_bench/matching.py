"""The nearest-graph classifier: a query takes the class of the training graphs it matches best.

An alternative to the GCN (``[training] classifier = "graph-match"``), for the same
training graphs. A query graph is compared with every training graph:

* **whole image**: the cosine similarity of the two whole-image nodes;
* **parts, matched part to part**: each part of one graph is paired with its most
  similar part of the other (cosine), both ways, and the two mean best similarities are
  averaged. A part that survives a change of viewpoint still finds its twin, whatever
  the other parts do; pooled into one vector (a mean, a GCN's readout) the parts repeat
  the whole image instead (cosine 0.99 between the two on the bench).
* **parts in place** (``layout_weight`` of the part match): the same, with each pair's
  cosine weighed by how near the two parts stand in their images, a Gaussian of the
  distance between their box centres (in image widths and heights, ``layout_sigma``).
  Where a thing stands in the view says where the camera is and where it looks, which
  a match anywhere in the image, and the whole image's bag of words, cannot see: most
  errors are a neighbouring cell looking the same way.
* **standardised parts** (``standardise``): each query part's best-twin similarities are
  standardised over the training graphs (less their mean, over their spread), and so are
  the graph-level terms, before they are averaged. Every part then has an equal say in
  which graphs match better than most: in a plain mean, a part whose similarities spread
  widely (it matches a few places very well and the rest badly, often by an accident of
  segmentation or synthesis) outvotes the many parts whose evidence is quieter but
  agrees. Scores are then in spreads, not cosines.
* **parts judged where drawn** (``weigh_drawn``): a pseudo-view is often half holes
  (where no source view saw), and a query part that stands where a training graph's
  image was not drawn can find no twin there, however right the place. Each query part's
  vote on a training graph is weighed by the share of that graph's image drawn at the
  part's centre (``SceneGraph.drawn``; a real view is drawn everywhere), so a pseudo-view
  is judged on what it shows; and each training part's own vote counts by the share drawn
  at its centre (a part cut out of a hole describes nothing seen). Without it, a nearly
  whole render of a neighbouring class outscores the true class's half-drawn one.
  ``drawn_prior`` starts each graph's weighted mean from that many parts' worth of its
  plain mean: a pseudo-view drawn under only a few of the query's parts (far from its
  source views, at L3) is then not judged on those few alone.
* **repeated parts counted once** (``burst``): a brick wall or a tiled floor is cut into
  many parts that all look alike (a bench query part has 5 to 6 others of its own image
  above cosine 0.85 on average), and each of them votes: an image that is mostly one texture is
  decided by that texture, wherever it appears, and the one part that tells the place
  (a doorway, a floor of another colour) is outvoted. Each part's vote counts
  ``n ** -burst_power``, ``n`` the parts of its own graph (itself included) above cosine
  ``burst`` to it: on both sides, the query's parts in each graph's mean and each training
  part in its graph's. This is the burstiness of visual words (Jégou, Douze and Schmid,
  CVPR 2009) at the level of parts.

* **the whole image whitened** (``whiten``): the whole-image cosine is taken after the
  training graphs' whole-image features are whitened by their scatter within each class
  (less the mean of all, times the within-class covariance to the power -1/2, shrunk
  towards the identity by ``whiten`` times its mean eigenvalue). A class's graphs are one
  place seen from a real view and from its pseudo-views, so what varies among them is
  what synthesis varies (holes, the room it guessed, blur), and whitening turns those
  directions down against those that tell one class from another: the within-class
  normalisation of metric learning and of whitened retrieval (Jégou and Chum, ECCV 2012),
  fitted on the training graphs alone. The ``nearest neighbour`` reference row stays plain.
  With ``whiten_parts`` the parts are compared in the same whitened space (each side's
  parts less the training parts' mean); which parts of an image repeat one another is
  still read on their plain cosines.
* **the parts whitened by what one part varies** (``part_groups`` with ``whiten_parts``):
  fitted on the whole images, the whitening turns down what synthesis varies in a whole
  image, not in a part. Where the training parts come in groups that are one real part
  (a class's real view's part and what each of its pseudo-views carried of it:
  ``SceneGraph.part_origins``), the parts are whitened instead by their own scatter
  about their group's mean, shrunk the same way: how synthesis changes one part (the
  pixels it blurred, the share of it that stayed in view) counts less than what tells
  one part from another. The plain scatter of a class's parts would not do: it is mostly
  how one image's parts differ from one another, which is what the match reads.
* **parts matched within their category** (``category_penalty``): where the parser names
  each part's category (``SceneGraph.categories``: a segmenter's class, a detector's), the
  cosine of a query part and a training part of different categories is lowered by this
  much before best twins are taken, where the other side holds a part of the part's category
  (the training graph, for a query part's twin in it; the query, for a training part's):
  at 2 or more a part's twin is of its own category wherever the other side has one. A wall
  whose texture looks like a floor's then does not pass for it: what the class says, which
  superpixels cannot. A graph without the category is judged on its parts' looks as before:
  lowered there too, the part's vote would turn into whether the graph holds the category,
  and a pseudo-view's holes leave out categories its place holds (with ground-truth classes
  on the `paper` preset's homes 161-162: +1.1 to +1.4 MRR points so, -3.7 to -6.3 lowered
  everywhere). With ``category_min_score`` a category counts only where the
  parser is that sure of it (``SceneGraph.category_scores``), so that a segmenter's guesses
  at a chair or a table do not keep parts from their twins.

The similarity of two graphs is ``whole_weight`` times the first plus the rest times the
part match (the whole image alone where either graph has no part), and a class scores the
best similarity of its training graphs, turned into probabilities by a softmax at
:data:`TEMPERATURE` (:data:`STANDARDISED_TEMPERATURE` for standardised parts). Nothing is
learned beyond the training graphs themselves, so nothing can fit a synthesis artefact
the way a classifier does; the ``nearest neighbour`` reference row of a report is this
rule with the whole image alone.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ssga_bench.bow import normalise_rows
from ssga_core.data import SceneGraph
from ssga_core.errors import InputError

TEMPERATURE = 0.05
"""Softmax temperature from class similarities to probabilities (ranks do not depend on it)."""

STANDARDISED_TEMPERATURE = 1.0
"""The same for standardised parts, whose similarities are in spreads over the training graphs, not cosines (their
spread over the classes is about 5 times the cosines'). Of 0.1, 0.25, 0.5 and 1.0, 1.0 gave the first 300 test views the
lowest mean negative log-likelihood of their true class on bench seed 0, a tuning seed (SIFT-SL (SPD): 4.67)."""

_NO_SPREAD = 1e-6
"""The least spread standardisation divides by: a part whose similarities are all equal over the training graphs stays 0."""


def standardised(x: np.ndarray, axis: int) -> np.ndarray:
    """``x`` less its mean, over its standard deviation, along ``axis``."""
    return (x - x.mean(axis=axis, keepdims=True)) / np.maximum(x.std(axis=axis, keepdims=True), _NO_SPREAD)


def drawn_grids(graphs: Sequence[SceneGraph]) -> np.ndarray:
    """``(graphs, B, B)``: each graph's ``drawn`` grid, all ones for a real view's (all of it seen)."""
    if not graphs:
        return np.zeros((0, 1, 1), np.float32)
    sides = {g.drawn.shape[0] for g in graphs if g.drawn is not None}
    if len(sides) > 1:
        raise InputError(f"graph matcher: the training graphs record where they were drawn on grids of different sizes {sorted(sides)}")
    side = sides.pop() if sides else 1
    return np.stack([g.drawn if g.drawn is not None else np.ones((side, side), np.float32) for g in graphs]).astype(np.float32)


def _unit(x: np.ndarray) -> np.ndarray:
    return normalise_rows(np.asarray(x, np.float32), "l2")


def burst_weights(parts: np.ndarray, threshold: float, power: float) -> np.ndarray:
    """``(parts,)`` each unit-length part's vote, ``n ** -power``, ``n`` the parts above cosine ``threshold`` to it (itself
    included): the parts of one image that repeat one another share a vote."""
    repeats = (parts @ parts.T > threshold).sum(axis=1)
    return np.maximum(repeats, 1).astype(np.float32) ** np.float32(-power)


def within_class_whitening(features: np.ndarray, labels: np.ndarray, shrink: float) -> tuple[np.ndarray, np.ndarray] | None:
    """``(mean, matrix)``: ``(x - mean) @ matrix`` whitens unit-length rows of ``features`` by their scatter about their
    class's mean, the covariance's eigenvalues shrunk by ``shrink`` times their mean (so that a direction no class
    varies in is not blown up); None where no class has two graphs that differ (nothing varies within a class)."""
    x = np.asarray(features, np.float64)
    classes, index = np.unique(labels, return_inverse=True)
    sums = np.zeros((len(classes), x.shape[1]))
    np.add.at(sums, index, x)
    deviations = x - (sums / np.bincount(index)[:, None])[index]
    eigenvalues, vectors = np.linalg.eigh(deviations.T @ deviations / len(x))
    floor = shrink * eigenvalues.clip(min=0).mean()
    if floor <= 1e-12:
        return None
    return x.mean(axis=0).astype(np.float32), (vectors / np.sqrt(eigenvalues.clip(min=0) + floor)).astype(np.float32)


def sure_categories(graph: SceneGraph, min_score: float) -> np.ndarray | None:
    """``(N,)``: each node's category (``SceneGraph.categories``), -1 where the parser's score for it
    (``SceneGraph.category_scores``) is below ``min_score``; None where the graph names none. A graph whose parser gives
    no scores (ground truth) keeps every category: nothing says it is unsure."""
    if graph.categories is None or not min_score or graph.category_scores is None:
        return graph.categories
    with np.errstate(invalid="ignore"):  # the whole image's NaN: below any score, and -1 already
        return np.where(graph.category_scores >= min_score, graph.categories, -1).astype(np.int32)


def part_centres(graph: SceneGraph) -> np.ndarray:
    """``(nodes, 2)`` each node's box centre in its image, in widths and heights from the whole image's corner."""
    whole = graph.boxes[0]
    size = np.maximum(whole[2:] - whole[:2], 1e-6)
    return (((graph.boxes[:, :2] + graph.boxes[:, 2:]) / 2 - whole[:2]) / size).astype(np.float32)


class GraphMatcher:
    """Class scores of query graphs by their best match among the training graphs.

    Args:
        features: ``(nodes, dim)`` every training graph's node features, graph after graph,
            scaled to unit length (:meth:`of` scales them).
        centres: ``(nodes, 2)`` each node's :func:`part_centres`.
        node_ptr: ``(graphs + 1,)`` where each graph's nodes start (its whole image first).
        labels: ``(graphs,)`` each training graph's class.
    """

    def __init__(
        self,
        features: np.ndarray,
        centres: np.ndarray,
        node_ptr: np.ndarray,
        labels: np.ndarray,
        num_classes: int,
        whole_weight: float,
        layout_weight: float = 0.0,
        layout_sigma: float = 0.3,
        standardise: bool = False,
        drawn: np.ndarray | None = None,
        drawn_prior: float = 0.0,
        burst: float | None = None,
        burst_power: float = 1.0,
        whiten: float | None = None,
        whiten_parts: bool = False,
        part_groups: np.ndarray | None = None,
        categories: np.ndarray | None = None,
        category_penalty: float = 0.0,
        category_min_score: float = 0.0,
    ) -> None:
        node_ptr, labels = np.asarray(node_ptr, np.int64), np.asarray(labels, np.int64)
        if (
            features.ndim != 2
            or centres.shape != (len(features), 2)
            or node_ptr.ndim != 1
            or len(node_ptr) != len(labels) + 1
            or node_ptr[-1] != len(features)
        ):
            raise InputError(
                f"graph matcher: {features.shape} node features, {centres.shape} node centres, {node_ptr.shape} graph offsets "
                f"and {labels.shape} labels do not fit together"
            )
        if not len(labels) or labels.min() < 0 or labels.max() >= num_classes:
            raise InputError(f"graph matcher: needs training graphs with classes in 0..{num_classes - 1}")
        if layout_sigma <= 0:
            raise InputError(f"graph matcher: layout_sigma must be positive, got {layout_sigma}")
        if drawn is not None and (drawn.ndim != 3 or len(drawn) != len(labels) or drawn.shape[1] != drawn.shape[2]):
            raise InputError(f"graph matcher: expected ({len(labels)}, B, B) drawn grids, one per training graph, got {drawn.shape}")
        if not np.isfinite(drawn_prior) or drawn_prior < 0:
            raise InputError(f"graph matcher: drawn_prior must be a count of parts (0 or more), got {drawn_prior}")
        if burst is not None and not -1 <= burst <= 1:
            raise InputError(f"graph matcher: burst is a cosine similarity (-1 to 1), got {burst}")
        if not np.isfinite(burst_power) or burst_power < 0:
            raise InputError(f"graph matcher: burst_power must be 0 or more, got {burst_power}")
        if whiten is not None and not (np.isfinite(whiten) and whiten > 0):
            raise InputError(f"graph matcher: whiten is a shrinkage (above 0), got {whiten}")
        if categories is not None and np.shape(categories) != (len(features),):
            raise InputError(f"graph matcher: expected a category for each of the {len(features)} training nodes, got {np.shape(categories)}")
        if not np.isfinite(category_penalty) or category_penalty < 0:
            raise InputError(f"graph matcher: category_penalty is a cosine to subtract (0 or more), got {category_penalty}")
        if not 0 <= category_min_score <= 1:
            raise InputError(f"graph matcher: category_min_score is a parser's score (0 to 1), got {category_min_score}")
        self.features, self.centres = np.asarray(features, np.float32), np.asarray(centres, np.float32)
        self.node_ptr, self.labels = node_ptr, labels
        self.num_classes, self.whole_weight = num_classes, whole_weight
        self.layout_weight, self.layout_sigma, self.standardise = layout_weight, layout_sigma, bool(standardise)
        starts, counts = node_ptr[:-1], np.diff(node_ptr)
        self._whole = self.features[starts]
        # The whole image whitened: the transform, and the training graphs' whole images in its space (None: plain).
        self.whiten = None if whiten is None else float(whiten)
        self._whitening = None if whiten is None else within_class_whitening(self._whole, labels, self.whiten)
        if self._whitening is not None:
            self._whole = self._whitened(self._whole)
        is_part = np.ones(len(self.features), bool)
        is_part[starts[counts > 0]] = False
        self._parts, self._part_centres = self.features[is_part], self.centres[is_part]
        # The training parts' side of _in_place's product: (x, y, 1, -|t|^2 / 2 sigma^2) per column.
        squared = -0.5 / np.float32(layout_sigma**2) * (self._part_centres**2).sum(axis=1, keepdims=True)
        self._train_in_place = np.concatenate([self._part_centres, np.ones_like(squared), squared], axis=1).T.copy()
        self._part_counts = counts - 1
        has = self._part_counts > 0
        self._with_parts = np.flatnonzero(has)
        self._part_starts = np.concatenate([[0], np.cumsum(self._part_counts)[:-1]])[has]
        # Parts judged where drawn: each training graph with parts' grid of drawn shares (None: not weighed).
        self.drawn = None if drawn is None else np.asarray(drawn, np.float32)
        self.drawn_prior = float(drawn_prior)
        self._drawn_with_parts = None if self.drawn is None else self.drawn[self._with_parts]
        self.burst, self.burst_power = (None if burst is None else float(burst)), float(burst_power)
        # Each training part's vote on its graph's side of the match: its own graph's drawn share at its centre (parts
        # judged where drawn) times its share of a repeated element (repeated parts counted once); None: all equal.
        self._train_part_votes = self._train_vote_totals = None
        if self.drawn is not None or self.burst is not None:
            votes = np.ones(len(self._parts), np.float32)
            if self.drawn is not None:
                owner = np.repeat(np.arange(len(labels)), counts)[is_part]
                votes *= self._drawn_share(self.drawn[owner], self._part_centres, diagonal=True)
            if self.burst is not None:
                for start, count in zip(self._part_starts, self._part_counts[self._with_parts]):
                    votes[start : start + count] *= burst_weights(self._parts[start : start + count], self.burst, self.burst_power)
            self._train_part_votes = votes
            self._train_vote_totals = np.maximum(np.add.reduceat(votes, self._part_starts), 1e-6)
        # The parts as the match compares them: whitened by their own groups' scatter, as the whole images are, or plain.
        self.whiten_parts = bool(whiten_parts) and whiten is not None
        self.part_groups = None if part_groups is None else np.asarray(part_groups, np.int64)
        if self.part_groups is not None and self.part_groups.shape != (len(self._parts),):
            raise InputError(f"graph matcher: expected a group for each of the {len(self._parts)} training parts, got {self.part_groups.shape}")
        self._part_whitening = None
        if self.whiten_parts and self.part_groups is not None:
            grouped = self.part_groups >= 0
            self._part_whitening = within_class_whitening(self._parts[grouped], self.part_groups[grouped], self.whiten)  # type: ignore[arg-type]
        whole_space = self.whiten_parts and self._part_whitening is None and len(self._parts)
        self._part_mean = self._parts.mean(axis=0) if whole_space else None
        self._compared_parts = self._compared(self._parts)
        # Parts matched within their category: each training node's category (-1: none named, or not sure enough); None:
        # not used. The query's categories count from category_min_score (the training ones were gated by `of`).
        self.categories = None if categories is None or not category_penalty else np.asarray(categories, np.int32)
        self.category_penalty = float(category_penalty) if self.categories is not None else 0.0
        self.category_min_score = float(category_min_score) if self.categories is not None else 0.0
        self._part_categories = None if self.categories is None else self.categories[is_part]

    @classmethod
    def of(
        cls,
        graphs: Sequence[SceneGraph],
        labels: Sequence[int],
        num_classes: int,
        whole_weight: float,
        layout_weight: float = 0.0,
        layout_sigma: float = 0.3,
        standardise: bool = False,
        weigh_drawn: bool = False,
        drawn_prior: float = 0.0,
        burst: float | None = None,
        burst_power: float = 1.0,
        whiten: float | None = None,
        whiten_parts: bool = False,
        part_groups: np.ndarray | None = None,
        category_penalty: float = 0.0,
        category_min_score: float = 0.0,
    ) -> GraphMatcher:
        """The matcher of ``graphs``; ``weigh_drawn``: judge the query's parts where each graph was drawn, each graph's
        weighted mean starting from ``drawn_prior`` parts' worth of its plain mean; ``burst``: count the parts of an
        image above this cosine to one another as one repeated element (``burst_power``: how far); ``whiten``: whiten
        the whole images by their scatter within each class, shrunk by this (``whiten_parts``: the parts too, by
        their scatter within ``part_groups`` where given, one group id per training part, -1 for none);
        ``category_penalty``: lower the cosine of two parts of different categories by this (parts matched within
        their category), where the graphs carry them; ``category_min_score``: only between categories the parser gave
        at least this score (:func:`sure_categories`)."""
        node_ptr = np.concatenate([[0], np.cumsum([g.num_nodes for g in graphs])])
        features = _unit(np.concatenate([g.features for g in graphs])) if graphs else np.zeros((0, 1), np.float32)
        centres = np.concatenate([part_centres(g) for g in graphs]) if graphs else np.zeros((0, 2), np.float32)
        drawn = drawn_grids(graphs) if weigh_drawn else None
        categories = None
        if category_penalty and any(g.categories is not None for g in graphs):
            named = [(sure_categories(g, category_min_score), g.num_nodes) for g in graphs]
            categories = np.concatenate([np.full(n, -1, np.int32) if c is None else c for c, n in named])
        return cls(
            features, centres, node_ptr, np.asarray(labels), num_classes, whole_weight, layout_weight, layout_sigma, standardise, drawn, drawn_prior,
            burst, burst_power, whiten, whiten_parts, part_groups, categories, category_penalty, category_min_score,
        )

    def state_dict(self) -> dict[str, np.ndarray]:
        return {
            "features": self.features,
            "centres": self.centres,
            "node_ptr": self.node_ptr,
            "labels": self.labels,
            "num_classes": np.array(self.num_classes),
            "whole_weight": np.array(self.whole_weight),
            "layout_weight": np.array(self.layout_weight),
            "layout_sigma": np.array(self.layout_sigma),
            "standardise": np.array(self.standardise),
            **({} if self.drawn is None else {"drawn": self.drawn, "drawn_prior": np.array(self.drawn_prior)}),
            **({} if self.burst is None else {"burst": np.array(self.burst), "burst_power": np.array(self.burst_power)}),
            **({} if self.whiten is None else {"whiten": np.array(self.whiten), "whiten_parts": np.array(self.whiten_parts)}),
            **({} if self.part_groups is None else {"part_groups": self.part_groups}),
            **({} if self.categories is None else {"categories": self.categories, "category_penalty": np.array(self.category_penalty)}),
            **({"category_min_score": np.array(self.category_min_score)} if self.category_min_score else {}),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, np.ndarray]) -> GraphMatcher:
        try:
            return cls(
                state["features"],
                state["centres"],
                state["node_ptr"],
                state["labels"],
                int(state["num_classes"]),
                float(state["whole_weight"]),
                float(state["layout_weight"]),
                float(state["layout_sigma"]),
                # A state saved before standardised parts (or parts judged where drawn) existed matched without them.
                bool(state.get("standardise", False)),
                state.get("drawn"),
                float(state.get("drawn_prior", 0.0)),
                float(state["burst"]) if "burst" in state else None,
                float(state.get("burst_power", 1.0)),
                float(state["whiten"]) if "whiten" in state else None,
                bool(state.get("whiten_parts", False)),
                state.get("part_groups"),
                state.get("categories"),
                float(state.get("category_penalty", 0.0)),
                float(state.get("category_min_score", 0.0)),
            )
        except KeyError as exc:
            raise InputError(f"graph matcher: saved state without {exc}") from None

    def _whitened(self, rows: np.ndarray, mean: np.ndarray | None = None) -> np.ndarray:
        """Unit-length rows in the whitened space (:func:`within_class_whitening`), less ``mean`` (default: the whole
        images' mean)."""
        whole_mean, matrix = self._whitening  # type: ignore[misc]
        return _unit((np.atleast_2d(rows) - (whole_mean if mean is None else mean)) @ matrix)

    def _compared(self, parts: np.ndarray) -> np.ndarray:
        """Parts as the match compares them (with ``whiten_parts``): where there are groups, less the grouped training
        parts' mean, whitened by their groups' scatter; else less the training parts' mean, as the whole images are; or plain."""
        if self._part_whitening is not None:
            mean, matrix = self._part_whitening
            return _unit((np.atleast_2d(parts) - mean) @ matrix)
        if self._part_mean is None or self._whitening is None:
            return parts
        return self._whitened(parts, self._part_mean)

    def _in_place(self, centres: np.ndarray) -> np.ndarray:
        """``(parts, 4)`` rows whose products with ``self._train_in_place`` are ``-|c - t|^2 / (2 sigma^2)``, the
        exponent of the nearness of a query part at ``c`` and a training part at ``t``: expanded into
        ``c.t / sigma^2 - |c|^2 / 2 sigma^2 - |t|^2 / 2 sigma^2``, one matrix product instead of a pass over every
        pair for each term (a query of 37 parts against 54,000 training parts: 33.6 ms written out, 8.9 ms so; one thread)."""
        scale = np.float32(1 / self.layout_sigma**2)
        squared = -0.5 * scale * (centres**2).sum(axis=1, keepdims=True)
        return np.concatenate([centres * scale, squared, np.ones_like(squared)], axis=1)

    @staticmethod
    def _drawn_share(grids: np.ndarray, centres: np.ndarray, diagonal: bool = False) -> np.ndarray:
        """The share drawn in the block of each grid (``(G, B, B)``) where each centre (``(N, 2)``, in image widths and
        heights) falls: ``(G, N)``, or with ``diagonal`` (G == N) the ``(N,)`` of each grid at its own centre."""
        blocks = grids.shape[1]
        row, col = (np.clip((centres[:, k] * blocks).astype(np.intp), 0, blocks - 1) for k in (1, 0))
        return grids[np.arange(len(grids)), row, col] if diagonal else grids[:, row, col]

    def _both_ways(
        self, pairs: np.ndarray, query_weights: np.ndarray | None = None, query_votes: np.ndarray | None = None, train_pairs: np.ndarray | None = None
    ) -> np.ndarray:
        """``(training graphs with parts,)``: from ``(query parts, every training part)`` similarities, each query part's
        best twin in each training graph and each training part's in the query, both means averaged; with
        standardised parts, each query part's twins and the training graphs' means are standardised over the graphs first.
        ``query_weights`` (query parts, training graphs with parts), with parts judged where drawn: how much each query
        part counts in each graph's mean (plus ``drawn_prior`` parts at the plain mean); each training part then counts
        by its own graph's drawn share at it. ``query_votes`` (query parts,), with repeated parts counted once: each query
        part's share of a vote, in every mean of the query's side (each training part's is set once, in ``__init__``).
        ``train_pairs``: the similarities each training part's twin in the query is taken from, where they differ from
        ``pairs`` (parts matched within their category)."""
        best_twins = np.maximum.reduceat(pairs, self._part_starts, axis=1)  # (query parts, training graphs with parts)
        train_best = (pairs if train_pairs is None else train_pairs).max(axis=0)
        if self._train_part_votes is None:
            train_to_query = np.add.reduceat(train_best, self._part_starts) / self._part_counts[self._with_parts]
        else:
            train_to_query = np.add.reduceat(train_best * self._train_part_votes, self._part_starts) / self._train_vote_totals
        if self.standardise:
            best_twins, train_to_query = standardised(best_twins, axis=1), standardised(train_to_query, axis=0)
        plain = best_twins.mean(axis=0) if query_votes is None else query_votes @ best_twins / query_votes.sum()
        if query_weights is None:
            query_to_train = plain
        else:  # a graph drawn nowhere under the query's parts: its plain mean (without a prior: average, 0 standardised)
            weights = query_weights if query_votes is None else query_weights * query_votes[:, None]
            query_to_train = ((weights * best_twins).sum(axis=0) + self.drawn_prior * plain) / np.maximum(weights.sum(axis=0) + self.drawn_prior, 1e-6)
        return (query_to_train + train_to_query) / 2

    def similarities(self, graph: SceneGraph) -> np.ndarray:
        """``(training graphs,)``: how well ``graph`` matches each training graph."""
        features = _unit(graph.features)
        similarity = self._whole @ (features[0] if self._whitening is None else self._whitened(features[0])[0])
        if self.standardise:  # in spreads too, to mix with the parts' (a per-query shift and scale: no rank changes)
            similarity = standardised(similarity, axis=0)
        parts = features[1:]
        if not len(parts) or not len(self._with_parts):
            return similarity
        pairs = self._compared(parts) @ self._compared_parts.T  # (query parts, every training part)
        penalties = self._across_categories(graph)
        centres = part_centres(graph)[1:]
        weights = None if self._drawn_with_parts is None else self._drawn_share(self._drawn_with_parts, centres).T
        votes = None if self.burst is None else burst_weights(parts, self.burst, self.burst_power)

        def both_ways(similarities: np.ndarray) -> np.ndarray:  # kept to their categories where they are matched so
            if penalties is None:
                return self._both_ways(similarities, weights, votes)
            query_side, train_side = penalties
            return self._both_ways(similarities - query_side, weights, votes, similarities - train_side)

        part_match = both_ways(pairs)
        if self.layout_weight > 0:
            nearness = np.exp(self._in_place(centres) @ self._train_in_place)
            part_match = (1 - self.layout_weight) * part_match + self.layout_weight * both_ways(pairs * nearness)
        matched = similarity.copy()
        matched[self._with_parts] = self.whole_weight * similarity[self._with_parts] + (1 - self.whole_weight) * part_match
        return matched

    def _across_categories(self, graph: SceneGraph) -> tuple[np.ndarray, np.ndarray] | None:
        """Two ``(query parts, every training part)`` penalties (parts matched within their category), each
        ``category_penalty`` where both parts name a category (one the parser is sure of: :func:`sure_categories`) and
        they differ, else 0: for each query part's twin in a training graph, where that graph holds a part of the query
        part's category; for each training part's twin in the query, where the query holds one of the training part's.
        None where either side names none."""
        named = None if self._part_categories is None else sure_categories(graph, self.category_min_score)
        if named is None:
            return None
        query, train = named[1:, None], self._part_categories[None, :]
        same = (query == train) & (query >= 0)
        across = ~same & (query >= 0) & (train >= 0)
        # Only where the other side holds the category: a graph without it is judged on its parts' looks, not on
        # lacking the category (a pseudo-view's holes leave out whole categories the query sees).
        graph_holds = np.repeat(np.logical_or.reduceat(same, self._part_starts, axis=1), self._part_counts[self._with_parts], axis=1)
        query_holds = same.any(axis=0, keepdims=True)
        penalty = np.float32(self.category_penalty)
        return penalty * (across & graph_holds), penalty * (across & query_holds)

    def class_similarities(self, graphs: Sequence[SceneGraph]) -> np.ndarray:
        """``(len(graphs), classes)``: each class's best training graph (a class without one: 1 below the query's worst)."""
        if not graphs:
            return np.zeros((0, self.num_classes), np.float32)
        similarity = np.stack([self.similarities(g) for g in graphs])
        out = np.repeat(similarity.min(axis=1, keepdims=True) - 1, self.num_classes, axis=1).astype(np.float32)
        order = np.argsort(self.labels, kind="stable")
        classes, starts = np.unique(self.labels[order], return_index=True)
        out[:, classes] = np.maximum.reduceat(similarity[:, order], starts, axis=1)
        return out

    def predict(self, graphs: Sequence[SceneGraph], batch_size: int | None = None) -> np.ndarray:
        """``(len(graphs), classes)`` class probabilities: a softmax of :meth:`class_similarities`."""
        logits = self.class_similarities(graphs) / (STANDARDISED_TEMPERATURE if self.standardise else TEMPERATURE)
        logits -= logits.max(axis=1, keepdims=True) if len(logits) else 0.0
        e = np.exp(logits)
        return (e / e.sum(axis=1, keepdims=True)).astype(np.float32)
