"""The nearest-graph classifier: a query takes the class of the training graphs it matches best.

An alternative to the GCN (``[training] classifier = "graph-match"``), for the same
training graphs. A query graph is compared with every training graph:

* **whole image**: the cosine similarity of the two whole-image nodes;
* **parts, matched part to part**: each part of one graph is paired with its most
  similar part of the other (cosine), both ways, and the two mean best similarities are
  averaged. A part that survives a change of viewpoint still finds its twin, whatever
  the other parts do; pooled into one vector (a mean, a GCN's readout) the parts repeat
  the whole image instead (cosine 0.99 between the two on the bench).

The similarity of two graphs is ``whole_weight`` times the first plus the rest times the
second (the whole image alone where either graph has no part), and a class scores the
best similarity of its training graphs, turned into probabilities by a softmax at
:data:`TEMPERATURE`. Nothing is learned beyond the training graphs themselves, so
nothing can fit a synthesis artefact the way a classifier does; the
``nearest neighbour`` reference row of a report is this rule with the whole image alone.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ssga_bench.bow import normalise_rows
from ssga_core.data import SceneGraph
from ssga_core.errors import InputError

TEMPERATURE = 0.05
"""Softmax temperature from class similarities to probabilities (ranks do not depend on it)."""


def _unit(x: np.ndarray) -> np.ndarray:
    return normalise_rows(np.asarray(x, np.float32), "l2")


class GraphMatcher:
    """Class scores of query graphs by their best match among the training graphs.

    Args:
        features: ``(nodes, dim)`` every training graph's node features, graph after graph,
            scaled to unit length (:meth:`of` scales them).
        node_ptr: ``(graphs + 1,)`` where each graph's nodes start (its whole image first).
        labels: ``(graphs,)`` each training graph's class.
    """

    def __init__(self, features: np.ndarray, node_ptr: np.ndarray, labels: np.ndarray, num_classes: int, whole_weight: float) -> None:
        node_ptr, labels = np.asarray(node_ptr, np.int64), np.asarray(labels, np.int64)
        if features.ndim != 2 or node_ptr.ndim != 1 or len(node_ptr) != len(labels) + 1 or node_ptr[-1] != len(features):
            raise InputError(
                f"graph matcher: {features.shape} node features, {node_ptr.shape} graph offsets and {labels.shape} labels do not fit together"
            )
        if not len(labels) or labels.min() < 0 or labels.max() >= num_classes:
            raise InputError(f"graph matcher: needs training graphs with classes in 0..{num_classes - 1}")
        self.features, self.node_ptr, self.labels = np.asarray(features, np.float32), node_ptr, labels
        self.num_classes, self.whole_weight = num_classes, whole_weight
        starts, counts = node_ptr[:-1], np.diff(node_ptr)
        self._whole = self.features[starts]
        self._parts = np.concatenate([self.features[s + 1 : s + n] for s, n in zip(starts, counts)]) if len(self.features) else self.features
        self._part_counts = counts - 1
        has = self._part_counts > 0
        self._with_parts = np.flatnonzero(has)
        self._part_starts = np.concatenate([[0], np.cumsum(self._part_counts)[:-1]])[has]

    @classmethod
    def of(cls, graphs: Sequence[SceneGraph], labels: Sequence[int], num_classes: int, whole_weight: float) -> GraphMatcher:
        node_ptr = np.concatenate([[0], np.cumsum([g.num_nodes for g in graphs])])
        features = _unit(np.concatenate([g.features for g in graphs])) if graphs else np.zeros((0, 1), np.float32)
        return cls(features, node_ptr, np.asarray(labels), num_classes, whole_weight)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {
            "features": self.features,
            "node_ptr": self.node_ptr,
            "labels": self.labels,
            "num_classes": np.array(self.num_classes),
            "whole_weight": np.array(self.whole_weight),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, np.ndarray]) -> GraphMatcher:
        try:
            return cls(state["features"], state["node_ptr"], state["labels"], int(state["num_classes"]), float(state["whole_weight"]))
        except KeyError as exc:
            raise InputError(f"graph matcher: saved state without {exc}") from None

    def similarities(self, graph: SceneGraph) -> np.ndarray:
        """``(training graphs,)``: how well ``graph`` matches each training graph."""
        features = _unit(graph.features)
        similarity = self._whole @ features[0]
        parts = features[1:]
        if not len(parts) or not len(self._with_parts):
            return similarity
        pairs = parts @ self._parts.T  # (query parts, every training part)
        # Each query part's best twin in each training graph, and each training part's in the query.
        query_to_train = np.maximum.reduceat(pairs, self._part_starts, axis=1).mean(axis=0)
        train_to_query = np.add.reduceat(pairs.max(axis=0), self._part_starts) / self._part_counts[self._with_parts]
        matched = similarity.copy()
        matched[self._with_parts] = self.whole_weight * similarity[self._with_parts] + (1 - self.whole_weight) * (
            query_to_train + train_to_query
        ) / 2
        return matched

    def class_similarities(self, graphs: Sequence[SceneGraph]) -> np.ndarray:
        """``(len(graphs), classes)``: each class's best training graph (-2 for a class without one)."""
        out = np.full((len(graphs), self.num_classes), -2.0, np.float32)
        if not graphs:
            return out
        similarity = np.stack([self.similarities(g) for g in graphs])
        order = np.argsort(self.labels, kind="stable")
        classes, starts = np.unique(self.labels[order], return_index=True)
        out[:, classes] = np.maximum.reduceat(similarity[:, order], starts, axis=1)
        return out

    def predict(self, graphs: Sequence[SceneGraph], batch_size: int | None = None) -> np.ndarray:
        """``(len(graphs), classes)`` class probabilities: a softmax of :meth:`class_similarities`."""
        logits = self.class_similarities(graphs) / TEMPERATURE
        logits -= logits.max(axis=1, keepdims=True) if len(logits) else 0.0
        e = np.exp(logits)
        return (e / e.sum(axis=1, keepdims=True)).astype(np.float32)
