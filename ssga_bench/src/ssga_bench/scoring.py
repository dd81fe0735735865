"""Scoring the query views, as the task a worker runs (:func:`score_chunk`): a chunk of test
or validation views, each loaded once and built into a graph by every trained variant
(its parts and local features from the feature cache), classified, and scored against the
nearest-neighbour reference."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ssga_bench.cache import FeatureCache
from ssga_bench.dataset import Dataset
from ssga_bench.execution import memo
from ssga_bench.io import load_npz
from ssga_bench.tasks import span
from ssga_bench.timings import Timings, instrument
from ssga_bench.variant_training import Trained, fitted_stages, load_classifier, whole_image_features
from ssga_core.data import Data, SceneGraph
from ssga_core.pipeline import BoundVariant, build_graph


SCORE_CHUNK = 64
"""Query views per scoring task (and per GCN prediction call): a fixed cut, so the scores
are the same whatever the executor; small enough for every worker to get its share."""


def query_channels(bound: BoundVariant) -> set[str]:
    """The dataset channels beyond RGB that the stages of ``bound``'s query path consume."""
    stages = [bound.descriptor, *([bound.parser] if bound.parser is not None and "P" in bound.variant.query_order else [])]
    consumed = set().union(*(type(stage).consumes for stage in stages))
    return {"rgb"} | ({"depth"} if Data.DEPTH in consumed else set()) | ({"semantic", "instance"} if Data.SEMANTIC in consumed else set())


def dataset_identity(dataset: Dataset) -> str:
    """What a dataset holds, as a string: its header and a digest of its plan (every view's id and pose)."""
    return json.dumps([dataset.header, hashlib.blake2b((dataset.root / "plan.json").read_bytes(), digest_size=8).hexdigest()], sort_keys=True)


def nearest_neighbour_scores(train: np.ndarray, labels: np.ndarray, queries: Sequence[SceneGraph], num_classes: int) -> np.ndarray:
    """``(queries, classes)``: cosine similarity of each query's whole-image node to the nearest
    training graph of each class (``train``: :func:`whole_image_features`; -1 for a class without one)."""
    similarity = whole_image_features(queries) @ train.T  # (Q, T)
    out = np.full((len(queries), num_classes), -1.0, dtype=np.float32)
    for c in np.unique(labels):
        out[:, c] = similarity[:, labels == c].max(axis=1)
    return out


@dataclass(frozen=True)
class ScoreJob:
    """A chunk of a split's views to score with every trained variant of a run.

    Attributes:
        ids: the views' sample ids, in the split's order.
        nearest: also score the nearest-neighbour reference (the test views).
        identity: the dataset's :func:`dataset_identity` (hashed once, by the driver).
    """

    dataset: str
    split: str
    ids: tuple[str, ...]
    variants: tuple[Trained, ...]
    cache: str
    nearest: bool
    identity: str

    def what(self) -> str:
        return f"scoring {span('view', self.ids)} ({self.split})"


@dataclass(frozen=True)
class ChunkScores:
    """What :func:`score_chunk` sends back: per trained variant, ``(views, classes)`` class
    probabilities and nearest-neighbour scores (None unless asked), and its timings."""

    probs: tuple[np.ndarray, ...]
    nearest: tuple[np.ndarray, ...] | None
    timings: Timings


@dataclass
class _Scorer:
    """A trained variant opened in a worker: its stages with the fitted descriptor, its GCN, its reference."""

    bound: BoundVariant
    model: Any
    train: np.ndarray
    labels: np.ndarray


def _open_trained(trained: Trained, timings: Timings) -> _Scorer:
    folder = Path(trained.folder)
    bound = fitted_stages(trained.variant, folder)  # the query path has no S: the oracle's synthesizer is not needed
    nearest = load_npz(folder / "nearest.npz")
    instrument(bound, timings)
    model = load_classifier(folder, trained.training.get("classifier", "gcn"))
    return _Scorer(bound, model, nearest["features"], nearest["labels"])


def score_chunk(job: ScoreJob) -> ChunkScores:
    """Class scores of a chunk of query views under every trained variant.

    Each view is loaded once for all variants, which build its graph in turn (its parts
    and local features come from the feature cache): variants that share a fitted
    dictionary then encode its features once (:data:`ssga_bench.bow.RECENT_CODES`).
    """
    from ssga_bench.tasks import opened_dataset

    dataset = opened_dataset(job.dataset)
    cache = memo(("feature cache", job.cache), lambda: FeatureCache(job.cache))
    keys = memo(("view keys", job.cache, job.identity), lambda: cache.view_keys(job.identity))

    # The variants are opened once per worker, instrumented with one timings object that
    # each chunk empties and sends back.
    def open_all() -> tuple[Timings, list[_Scorer]]:
        timings = Timings()
        return timings, [_open_trained(t, timings) for t in job.variants]

    timings, scorers = memo(("trained variants", tuple((t.folder, t.key) for t in job.variants)), open_all)
    timings.clear()
    channels = set().union(*(query_channels(s.bound) for s in scorers))
    graphs: list[list[SceneGraph]] = [[] for _ in scorers]
    for sample_id in job.ids:
        sample = dataset.sample(sample_id)
        key = keys.get(sample_id)
        with timings.phase("load views"):
            view = dataset.view(sample, channels=channels) if key is not None else dataset.view(sample)
        timings.views["load views"] += 1
        if key is not None:
            cache.know(view, key)
        for scorer, built in zip(scorers, graphs):
            built.append(build_graph(scorer.bound, view, memo=cache))
    with timings.phase("evaluate"):
        probs = tuple(s.model.predict(g, batch_size=SCORE_CHUNK) for s, g in zip(scorers, graphs))
        nearest = (
            tuple(nearest_neighbour_scores(s.train, s.labels, g, dataset.num_classes) for s, g in zip(scorers, graphs)) if job.nearest else None
        )
    return ChunkScores(probs, nearest, timings.take())
