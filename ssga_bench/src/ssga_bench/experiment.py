"""Running an experiment: every variant trained and scored on a dataset, fused, reported.

For each variant:

1. **Training graphs.** This module draws, per cell, the poses of every class's
   pseudo-training graphs (the class's training viewpoint and ``synthetic_per_class - 1``
   jittered copies, :func:`training_cells`); the pipeline
   (:func:`ssga_core.pipeline.training_graphs`) fits the descriptor and builds the
   graphs as the variant's order says, synthesizing or not. The runner never branches
   on the order and never calls a stage itself.
2. **Train** the variant's classifier, the GCN or graph matching (one task per variant,
   :func:`train_variant`), then
   **score** every test and validation view (the query path,
   :func:`ssga_core.pipeline.build_graph`) in chunks, each chunk through every trained
   variant (:func:`score_chunk`).

Then the fuser combines the variants' class probabilities and every row is evaluated
per difficulty level (:mod:`ssga_bench.evaluation`).

Outputs in the experiment folder: ``variants/<label>/`` (``gcn.pt`` or ``matcher.npz``,
``descriptor.npz``, ``nearest.npz``, ``training.json``, ``scores.npy``...),
``report.md``, ``results.csv``, ``results.png``, ``timings.json``. Each variant's
outputs are keyed by a hash of everything they depend on, so a rerun skips finished
variants, an interrupted run trains only the variants it had not trained and scores
only the chunks of views it had not scored (``scoring/``, removed once every variant's
scores are written).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import re
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ssga_bench.bow import normalise_rows
from ssga_bench.cache import FeatureCache, stage_key
from ssga_bench.config import Experiment, TrainingConfig
from ssga_bench.dataset import FITTED, Dataset, build_workspace
from ssga_bench.evaluation import Report, truth_ranks
from ssga_bench.execution import Executor, memo, open_executor
from ssga_bench.figures import birdseye, scene_graph_pictures
from ssga_bench.gcn import load_gcn, save_gcn, train_gcn
from ssga_bench.io import atomic_write_bytes, load_npy, load_npz, npy_bytes, npz_bytes, read_json, warn, writable_folder, write_json, write_png
from ssga_bench.learned import Learned
from ssga_bench.matching import GraphMatcher
from ssga_bench.oracle import TrueRender
from ssga_bench.page import write_run_page
from ssga_bench.protocol import Protocol, Sample
from ssga_bench.queries import draw_queries, save_predictions
from ssga_bench.tasks import chunks, span
from ssga_bench.workspace import Workspace
from ssga_core.config import ResolvedStage, ResolvedVariant
from ssga_core.data import Data, Regions, SceneGraph, View
from ssga_core.errors import MissingWeightsError, PluginError, SsgaError
from ssga_core.geometry import Pose
from ssga_core.pipeline import BoundVariant, CellTraining, Progress, PseudoView, build_graph, training_graphs
from ssga_core.stages import Descriptor, Fuser, LocalDescriptor, Synthesizer


@dataclass
class Timings:
    """Where the time goes.

    Attributes:
        seconds: per stage and phase of the work (load views, parse, describe,
            synthesize, train, evaluate...), summed over every worker that did it: what
            each costs, whatever the executor.
        wall: per phase of the run as the driver waits for it (workspace, real views,
            variants, report): with several workers, less than the work it holds.
        views: how many views each per-view stage handled (for its rate, views per second).
    """

    seconds: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    wall: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    views: dict[str, int] = field(default_factory=lambda: defaultdict(int))

    def phase(self, name: str) -> AbstractContextManager[None]:
        """Time the block as work of ``name``."""
        return _timed(self.seconds, name)

    def wall_phase(self, name: str) -> AbstractContextManager[None]:
        """Time the block as a phase of the run the driver waits for."""
        return _timed(self.wall, name)

    def add(self, other: Timings | Mapping[str, float]) -> None:
        """Add another's figures (a worker's)."""
        if isinstance(other, Timings):
            for phase, seconds in other.wall.items():
                self.wall[phase] += seconds
            for stage, count in other.views.items():
                self.views[stage] += count
            other = other.seconds
        for phase, seconds in other.items():
            self.seconds[phase] += seconds

    def clear(self) -> None:
        for figures in (self.seconds, self.wall, self.views):
            figures.clear()

    def take(self) -> Timings:
        """A copy of the figures, which are then cleared (a worker's, sent back per task)."""
        out = Timings()
        out.add(self)
        self.clear()
        return out

    def to_json(self) -> dict[str, dict[str, float]]:
        return {"wall": dict(self.wall), "work": dict(self.seconds), "views": dict(self.views)}

    def wrap(self, obj: object, method: str, phase: str, per_view: bool = False) -> None:
        """Time every call of ``obj.method`` under ``phase`` (an instance attribute shadows the
        method); ``per_view``: each call handles one view, counted for the phase's rate."""
        inner = getattr(obj, method)

        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.phase(phase):
                out = inner(*args, **kwargs)
            if per_view:
                self.views[phase] += 1
            return out

        setattr(obj, method, timed)


@contextmanager
def _timed(into: dict[str, float], name: str) -> Iterator[None]:
    start = time.perf_counter()
    try:
        yield
    finally:
        into[name] += time.perf_counter() - start


def instrument(bound: BoundVariant, timings: Timings) -> None:
    if bound.parser is not None:
        timings.wrap(bound.parser, "parse", "parse", per_view=True)
    phases = {"extract": "describe", "describe": "describe", "pool": "pool (node features)", "fit": "fit descriptor"}
    for method, phase in phases.items():
        if hasattr(bound.descriptor, method):
            timings.wrap(bound.descriptor, method, phase, per_view=method in ("extract", "describe"))
    if bound.synthesizer is not None:
        timings.wrap(bound.synthesizer, "synthesize", "synthesize", per_view=True)


def jittered(pose: Pose, rng: np.random.Generator, metres: float, degrees: float) -> Pose:
    r, phi = metres * math.sqrt(rng.random()), rng.random() * 2 * math.pi
    yaw = pose.yaw + math.radians(degrees) * (2 * rng.random() - 1)
    return Pose(pose.x + r * math.cos(phi), pose.y + r * math.sin(phi), yaw, pose.height)


@dataclass(frozen=True)
class TrainingPlan:
    """What every variant of an experiment learns from (the same for all of them).

    Attributes:
        cells: each cell's real view.
        pseudo: the pseudo-views a variant with S synthesizes.
        pose_groups: per pseudo-view, the pose it was drawn as (jittered copies of one
            canonical viewpoint share one): the classifier holds out whole groups for
            early stopping, so its validation never differs from training by a jitter only.
    """

    cells: list[CellTraining]
    pseudo: list[PseudoView]
    pose_groups: list[int]

    def groups(self, real_graphs: int, synthesizes: bool) -> np.ndarray:
        """The group of every training graph (:func:`ssga_core.pipeline.training_graphs`'s order):
        the real graphs each their own, then, for a variant with S, the pseudo-views'."""
        pseudo = real_graphs + np.asarray(self.pose_groups if synthesizes else [], dtype=np.int64)
        return np.concatenate([np.arange(real_graphs), pseudo]).astype(np.int64)


def training_plan(dataset: Dataset, config: TrainingConfig, views: Views) -> TrainingPlan:
    """Each cell's real view, and the pose and source views of every class's pseudo-views, seeded.

    Poses (``config.poses``): ``"class"`` draws ``synthetic_per_class`` poses over the
    region of poses of each class, as the protocol draws test views; ``"canonical"`` gives
    a class without a real view its training viewpoint and ``synthetic_per_class - 1``
    jittered copies (the real class: the jittered copies beside its real view).

    Sources (``config.sources``): ``"own"`` renders a class from its cell's real view;
    ``"seen"`` adds the other cells' real views that see at least ``min_source_coverage``
    of the floor the pose sees, most first, up to ``max_sources`` in all.
    """
    rng = np.random.default_rng(config.seed)
    train = dataset.split("train")
    rank_of_cell = {cell: rank for rank, cell in enumerate(dataset.plan.cells)}
    orientations = dataset.plan.config.orientations
    cells = []
    for s in train:
        rank = rank_of_cell[s.cell]
        cells.append(CellTraining(views(s, keep=True), s.place, range(rank * orientations, (rank + 1) * orientations)))
    index_of_rank = {rank_of_cell[s.cell]: i for i, s in enumerate(train)}
    protocol = Protocol(dataset.floor_plan, dataset.camera, dataset.plan.config)

    drawn: list[tuple[int, Pose, int]] = []  # (place, pose, group)
    if config.poses == "class":
        height = train[0].pose.height
        for place, poses in sorted(protocol.class_poses(dataset.plan.cells, config.synthetic_per_class, height, rng).items()):
            drawn.extend([(place, pose, len(drawn) + i) for i, pose in enumerate(poses)])
    else:
        for group, s in enumerate(sorted(dataset.split("train") + dataset.split("target"), key=lambda s: s.place)):
            first = [] if s.split == "train" else [s.pose]
            jitters = [jittered(s.pose, rng, config.jitter_m, config.jitter_deg) for _ in range(config.synthetic_per_class - 1)]
            drawn.extend((s.place, pose, group) for pose in first + jitters)

    real_polygons = [protocol.polygon(s.pose) for s in train]
    pseudo = []
    for place, pose, _ in drawn:
        own = index_of_rank[place // orientations]
        sources = [own]
        if config.sources == "seen" and config.max_sources > 1:
            seen = protocol.polygon(pose)
            area = seen.area
            coverage = [(seen.intersection(poly).area / area if area > 0 else 0.0, i) for i, poly in enumerate(real_polygons) if i != own]
            ranked = sorted((c, i) for c, i in coverage if c >= config.min_source_coverage)[::-1]
            sources += [i for _, i in ranked[: config.max_sources - 1]]
        pseudo.append(PseudoView(place, pose, tuple(sources)))
    return TrainingPlan(cells, pseudo, [group for _, _, group in drawn])


def folder_names(labels: Iterable[str]) -> dict[str, str]:
    """A folder name for each variant label: readable (``P-SL (PDS)`` -> ``P-SL_PDS``), and
    never shared by two labels (``x y`` and ``x/y``, or ``PD`` and ``pd`` on a file system that
    ignores case) nor outside the output folder (``..``): a name that would be gets a short
    hash of its label."""
    labels = list(labels)
    readable = {label: re.sub(r"[^A-Za-z0-9._-]+", "_", label).strip("_.") for label in labels}
    taken = Counter(name.lower() for name in readable.values())
    names = {}
    for label, name in readable.items():
        if not name or taken[name.lower()] > 1:
            name = f"{name or 'variant'}-{hashlib.blake2b(label.encode(), digest_size=3).hexdigest()}"
        names[label] = name
    return names


def variant_key(rv: ResolvedVariant, training: TrainingConfig, dataset: Dataset, extra: str = "") -> str:
    spec = {
        "extra": extra,
        "variant": str(rv.variant),
        "stages": {k: [s.cls.name, s.config.model_dump(mode="json")] for k, s in sorted(rv.stages.items())},
        "training": training.model_dump(mode="json"),
        "dataset": dataset.header,
        "plan": hashlib.blake2b((dataset.root / "plan.json").read_bytes(), digest_size=8).hexdigest(),
    }
    return hashlib.blake2b(json.dumps(spec, sort_keys=True).encode(), digest_size=10).hexdigest()


class Views:
    """Loads dataset views (timed), keeping the few real training views in memory."""

    def __init__(self, dataset: Dataset, timings: Timings) -> None:
        self.dataset, self.timings = dataset, timings
        self._kept: dict[str, View] = {}

    def __call__(self, sample: Sample, keep: bool = False) -> View:
        if sample.id in self._kept:
            return self._kept[sample.id]
        with self.timings.phase("load views"):
            view = self.dataset.view(sample)
        self.timings.views["load views"] += 1
        if keep:
            self._kept[sample.id] = view
        return view


def query_channels(bound: BoundVariant) -> set[str]:
    """The dataset channels beyond RGB that the stages of ``bound``'s query path consume."""
    stages = [bound.descriptor, *([bound.parser] if bound.parser is not None and "P" in bound.variant.query_order else [])]
    consumed = set().union(*(type(stage).consumes for stage in stages))
    return {"rgb"} | ({"depth"} if Data.DEPTH in consumed else set()) | ({"semantic", "instance"} if Data.SEMANTIC in consumed else set())


def dataset_identity(dataset: Dataset) -> str:
    """What a dataset holds, as a string: its header and a digest of its plan (every view's id and pose)."""
    return json.dumps([dataset.header, hashlib.blake2b((dataset.root / "plan.json").read_bytes(), digest_size=8).hexdigest()], sort_keys=True)


@dataclass(frozen=True)
class VariantResult:
    """What one variant left: its scores on the test and validation views, and a reference.

    Attributes:
        test: ``(test views, classes)`` class probabilities of the variant's GCN.
        nearest: ``(test views, classes)`` a nearest-neighbour baseline over the same
            features: the cosine similarity of the query's whole-image node to the
            nearest training graph of each class.
        val: ``(validation views, classes)`` the GCN's probabilities (empty without a
            validation split).
        training: the classifier's training record (``training.json``).
    """

    test: np.ndarray
    nearest: np.ndarray
    val: np.ndarray
    training: dict[str, Any]


_OUTPUTS = {"test": "scores.npy", "nearest": "nn_scores.npy", "val": "val_scores.npy"}
_TRAINED = ("descriptor.npz", "nearest.npz")
"""What a trained variant's folder holds for the scoring tasks, besides ``training.json`` and its classifier."""
CLASSIFIER_FILES = {"gcn": "gcn.pt", "graph-match": "matcher.npz"}
"""Each ``[training] classifier``'s file in a trained variant's folder."""

SCORE_CHUNK = 64
"""Query views per scoring task (and per GCN prediction call): a fixed cut, so the scores
are the same whatever the executor; small enough for every worker to get its share."""


@dataclass(frozen=True)
class Trained:
    """A trained variant, as its folder holds it: what a scoring task needs to score with it.

    Attributes:
        folder: the classifier (``gcn.pt``, or ``matcher.npz`` for graph matching),
            ``descriptor.npz`` (the descriptor's fitted state),
            ``nearest.npz`` (the training graphs' whole-image features and classes, for
            the nearest-neighbour reference) and ``training.json`` (the classifier's
            training record, with the variant's ``key``).
    """

    variant: ResolvedVariant
    folder: str
    key: str
    training: dict[str, Any] = field(compare=False, repr=False)


def train_variant_in(
    rv: ResolvedVariant,
    dataset: Dataset,
    training: TrainingConfig,
    plan: TrainingPlan,
    folder: Path,
    cache: FeatureCache,
    views: Views,
    timings: Timings,
    progress: Progress | None = None,
    *,
    synthesizer: Synthesizer | None = None,
) -> Trained:
    """Build one variant's training graphs, fit its descriptor, train its GCN, and leave them in
    ``folder`` (resuming: a variant trained before with the same key is not trained again).

    Args:
        synthesizer: replaces the variant's own (the oracle's true renders).
    """
    extra = synthesizer.name if synthesizer is not None else ""
    key = variant_key(rv, training, dataset, extra=extra)
    trained = _trained(rv, folder, key)
    if trained is not None:
        return trained
    # Scores of an earlier training (another key) must not pass for this one's.
    for file in _OUTPUTS.values():
        (folder / file).unlink(missing_ok=True)

    bound = rv.bind()
    if synthesizer is not None:
        bound = dataclasses.replace(bound, synthesizer=synthesizer, label=f"{bound.label} on {synthesizer.name}s")
    instrument(bound, timings)
    graphs, labels = training_graphs(
        bound, plan.cells, plan.pseudo, real_for_every_class=training.real_for_every_class, memo=cache, progress=progress
    )
    synthesizes = bound.synthesizer is not None
    groups = plan.groups(len(graphs) - (len(plan.pseudo) if synthesizes else 0), synthesizes)
    with timings.phase("train"):
        fitted = _fit_classifier(graphs, labels, groups, dataset.num_classes, training, folder)
    atomic_write_bytes(folder / "descriptor.npz", npz_bytes(fitted_state(bound.descriptor)))
    atomic_write_bytes(folder / "nearest.npz", npz_bytes({"features": whole_image_features(graphs), "labels": np.asarray(labels, np.int64)}))
    record = {"key": key, "label": bound.label, "graphs": len(graphs), "classifier": training.classifier, **fitted}
    write_json(folder / "training.json", record)  # last: the folder is a trained variant once it is there
    return Trained(rv, str(folder), key, record)


def _fit_classifier(
    graphs: Sequence[SceneGraph], labels: Sequence[int], groups: np.ndarray, num_classes: int, training: TrainingConfig, folder: Path
) -> dict[str, Any]:
    """Fit the variant's classifier (``training.classifier``) and save it in ``folder``; returns its training record."""
    if training.classifier == "graph-match":
        matcher = GraphMatcher.of(graphs, labels, num_classes, training.match_whole)
        atomic_write_bytes(folder / CLASSIFIER_FILES["graph-match"], npz_bytes(matcher.state_dict()))
        return {"match_whole": training.match_whole}
    model, report = train_gcn(graphs, np.array(labels), num_classes, training, groups=groups)
    save_gcn(model, folder / CLASSIFIER_FILES["gcn"])
    return asdict(report)


def _load_classifier(folder: Path, kind: str) -> Any:
    """The classifier :func:`_fit_classifier` saved: anything with ``predict(graphs) -> (graphs, classes)``."""
    if kind == "graph-match":
        return GraphMatcher.from_state(load_npz(folder / CLASSIFIER_FILES[kind]))
    return load_gcn(folder / CLASSIFIER_FILES["gcn"])


def _trained(rv: ResolvedVariant, folder: Path, key: str) -> Trained | None:
    try:
        record = read_json(folder / "training.json") if (folder / "training.json").exists() else None
    except SsgaError:
        return None
    if not isinstance(record, dict) or record.get("key") != key:
        return None
    files = (*_TRAINED, CLASSIFIER_FILES.get(record.get("classifier", "gcn"), "?"))
    return Trained(rv, str(folder), key, record) if all((folder / f).exists() for f in files) else None


def fitted_state(descriptor: Descriptor) -> dict[str, np.ndarray]:
    """What ``descriptor`` learned in ``fit``, for the scoring workers (:meth:`Descriptor.state_dict`)."""
    state = descriptor.state_dict()
    if not state and type(descriptor).fit is not Descriptor.fit:
        raise PluginError(
            f"descriptor {descriptor.name!r} ({type(descriptor).__module__}) learns in fit() but its state_dict() is empty: "
            "write state_dict and load_state_dict, so that other processes score with what it learned (docs/writing_plugins.md)"
        )
    return state


def whole_image_features(graphs: Sequence[SceneGraph]) -> np.ndarray:
    """``(graphs, dim)``: each graph's whole-image node feature, scaled to unit length."""
    x = np.stack([g.features[0] for g in graphs]).astype(np.float32) if graphs else np.zeros((0, 1), np.float32)
    return normalise_rows(x, "l2")


def nearest_neighbour_scores(train: np.ndarray, labels: np.ndarray, queries: Sequence[SceneGraph], num_classes: int) -> np.ndarray:
    """``(queries, classes)``: cosine similarity of each query's whole-image node to the nearest
    training graph of each class (``train``: :func:`whole_image_features`; -1 for a class without one)."""
    similarity = whole_image_features(queries) @ train.T  # (Q, T)
    out = np.full((len(queries), num_classes), -1.0, dtype=np.float32)
    for c in np.unique(labels):
        out[:, c] = similarity[:, labels == c].max(axis=1)
    return out


def finished_variant(rv: ResolvedVariant, dataset: Dataset, training: TrainingConfig, folder: Path, extra: str = "") -> VariantResult | None:
    """What a finished run of this variant left in ``folder`` (``extra``: the oracle's synthesizer), or None."""
    key = variant_key(rv, training, dataset, extra=extra)
    shapes = {"test": len(dataset.split("test")), "nearest": len(dataset.split("test")), "val": len(dataset.split("val"))}
    return _finished(folder, key, {k: (n, dataset.num_classes) for k, n in shapes.items()})


def _finished(folder: Path, key: str, shapes: dict[str, tuple[int, int]]) -> VariantResult | None:
    """What a finished run of this variant left, or None; damaged outputs are recomputed, with a warning."""
    meta_path = folder / "training.json"
    if not (meta_path.exists() and all((folder / f).exists() for f in _OUTPUTS.values())):
        return None
    try:
        meta = read_json(meta_path)
        if meta.get("key") != key:
            return None
    except (SsgaError, AttributeError):
        warn(f"{meta_path}: damaged; training this variant again")
        return None
    arrays = {name: load_npy(folder / file, shapes[name], what="scores") for name, file in _OUTPUTS.items()}
    if any(a is None for a in arrays.values()):
        return None
    return VariantResult(training=meta, **arrays)


@dataclass(frozen=True)
class VariantJob:
    """One variant to train, as a task (:func:`train_variant`) ships it to a worker.

    Attributes:
        oracle: the workspace source, to train on its true renders at the same poses
            (the oracle row) instead of the variant's syntheses.
    """

    variant: ResolvedVariant
    dataset: str
    training: TrainingConfig
    plan: TrainingPlan
    folder: str
    cache: str
    oracle: ResolvedStage | None = None

    def what(self) -> str:
        return f"variant {self.variant.label}" + (" on true renders (oracle)" if self.oracle is not None else "")


@dataclass(frozen=True)
class VariantOutcome:
    """What :func:`train_variant` sends back: the trained variant, or why it could not run, and its timings."""

    trained: Trained | None
    not_run: str
    timings: Timings


def train_variant(job: VariantJob) -> VariantOutcome:
    """Train one variant (resuming: :func:`train_variant_in`); a missing checkpoint is an outcome, not a failure."""
    from ssga_bench.tasks import opened_dataset, opened_workspace

    timings = Timings()
    dataset = opened_dataset(job.dataset)
    # One cache per process: the variants a worker runs share what they computed of the
    # same synthetic views (SD, SPD and DSP render the same pseudo-views).
    cache = memo(("feature cache", job.cache), lambda: FeatureCache(job.cache))
    synthesizer = TrueRender(opened_workspace(job.oracle)) if job.oracle is not None else None
    views = Views(dataset, timings)
    try:
        trained = train_variant_in(job.variant, dataset, job.training, job.plan, Path(job.folder), cache, views, timings, synthesizer=synthesizer)
    except MissingWeightsError as exc:
        return VariantOutcome(None, f"no weights: {exc}", timings)
    return VariantOutcome(trained, "", timings)


# -- scoring the query views ------------------------------------------------------------------


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
    bound = trained.variant.bind()
    folder = Path(trained.folder)
    bound.descriptor.load_state_dict(load_npz(folder / "descriptor.npz"))
    nearest = load_npz(folder / "nearest.npz")
    instrument(bound, timings)
    model = _load_classifier(folder, trained.training.get("classifier", "gcn"))
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


def score_queries(
    trained: Sequence[Trained],
    dataset: Dataset,
    out: Path,
    cache: FeatureCache,
    executor: Executor,
    timings: Timings,
    progress: Progress | None = None,
) -> list[VariantResult]:
    """Score the test and validation views with every trained variant, in chunks on the
    executor's workers; write each variant's score files and return its result.

    Each finished chunk is kept in ``out/scoring/<digest>/`` (the digest names the trained
    variants) until every variant's scores are written, so an interrupted run scores only
    the chunks it had not finished.
    """
    if not trained:
        return []
    digest = hashlib.blake2b(json.dumps([t.key for t in trained]).encode(), digest_size=8).hexdigest()
    folder = out / "scoring" / digest
    root, cache_folder = str(dataset.root.resolve()), str(cache.root.resolve())  # type: ignore[union-attr]
    identity = dataset_identity(dataset)
    jobs: list[tuple[str, int, ScoreJob]] = []
    for split in ("test", "val"):
        ids = [s.id for s in dataset.split(split)]
        for i, chunk in enumerate(chunks(ids, SCORE_CHUNK)):
            jobs.append((split, i, ScoreJob(root, split, chunk, tuple(trained), cache_folder, split == "test", identity)))

    def chunk_file(split: str, i: int) -> Path:
        return folder / f"{split}-{i:06d}.npz"

    def read_chunk(split: str, i: int, job: ScoreJob) -> ChunkScores | None:
        path = chunk_file(split, i)
        if not path.exists():
            return None
        try:
            arrays = load_npz(path)
        except SsgaError:
            return None  # cut short by a full disk, say: scored again
        n, shape = len(trained), (len(job.ids), dataset.num_classes)
        names = [f"probs-{v}" for v in range(n)] + ([f"nearest-{v}" for v in range(n)] if job.nearest else [])
        if any(name not in arrays or arrays[name].shape != shape for name in names):
            return None
        nearest = tuple(arrays[f"nearest-{v}"] for v in range(n)) if job.nearest else None
        return ChunkScores(tuple(arrays[f"probs-{v}"] for v in range(n)), nearest, Timings())

    kept = {(split, i): read_chunk(split, i, job) for split, i, job in jobs}
    todo = [(split, i, job) for split, i, job in jobs if kept[(split, i)] is None]
    total = sum(len(job.ids) for _, _, job in jobs)
    done = sum(len(job.ids) for split, i, job in jobs if kept[(split, i)] is not None)
    for (split, i, job), scores in zip(todo, executor.map(score_chunk, [job for _, _, job in todo], describe=ScoreJob.what)):
        arrays = {f"probs-{v}": p for v, p in enumerate(scores.probs)}
        arrays |= {f"nearest-{v}": p for v, p in enumerate(scores.nearest or ())}
        atomic_write_bytes(chunk_file(split, i), npz_bytes(arrays))
        timings.add(scores.timings)
        kept[(split, i)] = scores
        done += len(job.ids)
        if progress:
            progress("score the query views", done, total)

    def joined(split: str, v: int, nearest: bool = False) -> np.ndarray:
        parts = [np.zeros((0, dataset.num_classes), np.float32)]
        for s, i, _ in jobs:
            if s == split:
                scores = kept[(s, i)]
                assert scores is not None and (not nearest or scores.nearest is not None)
                parts.append(scores.nearest[v] if nearest else scores.probs[v])  # type: ignore[index]
        return np.concatenate(parts)

    results = []
    for v, t in enumerate(trained):
        result = VariantResult(test=joined("test", v), nearest=joined("test", v, nearest=True), val=joined("val", v), training=t.training)
        for name, file in _OUTPUTS.items():
            atomic_write_bytes(Path(t.folder) / file, npy_bytes(getattr(result, name)))
        results.append(result)
    # Every variant's scores are written: the chunks are not needed any more (ssga wrote them).
    for split, i, _ in jobs:
        chunk_file(split, i).unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        folder.rmdir()
        folder.parent.rmdir()  # only if no other run's chunks are there
    return results


def cached_stages(variants: Sequence[ResolvedVariant]) -> list[ResolvedStage]:
    """The stages whose output on real views the feature cache holds: the parsers of the
    variants whose queries are parsed, and the local descriptors (each once)."""
    stages: dict[tuple[str, str], ResolvedStage] = {}
    for rv in variants:
        parser = rv.stages.get("parser")
        if parser is not None and "P" in rv.variant.query_order:
            stages.setdefault((parser.cls.__qualname__, parser.config.model_dump_json()), parser)
        descriptor = rv.stages["descriptor"]
        if issubclass(descriptor.cls, LocalDescriptor):
            stages.setdefault((descriptor.cls.__qualname__, descriptor.config.model_dump_json()), descriptor)
    return list(stages.values())


def describe_real_views(
    variants: Sequence[ResolvedVariant],
    dataset: Dataset,
    cache: FeatureCache,
    executor: Executor,
    batch: int,
    timings: Timings,
    progress: Progress | None = None,
) -> None:
    """Parse and describe every real view (training, test, validation) once, for every
    variant, on the executor's workers in chunks of ``batch`` views; the cache keeps the
    results, and what it already holds is not computed again."""
    from ssga_bench.tasks import DescribeJob, chunks, describe_views

    # A stage that stored every view of this dataset before (a rerun) is not asked again:
    # no view is loaded to look.
    identity = dataset_identity(dataset)
    stages = tuple(stage for stage in cached_stages(variants) if not cache.complete(stage, identity))
    if not stages:
        return
    ids = [s.id for split in ("train", "test", "val") for s in dataset.split(split)]
    # Absolute paths: a Ray worker does not run in this folder.
    root = str(cache.root.resolve()) if cache.root is not None else None
    jobs = [DescribeJob(str(dataset.root.resolve()), chunk, stages, root) for chunk in chunks(ids, batch)]
    done = 0
    incomplete: set[str] = set()
    keys: dict[str, str] = {}
    for described in executor.map(describe_views, jobs, describe=DescribeJob.what):
        incomplete.update(described.without_weights)
        keys.update(described.view_keys)
        for key, entry in described.entries:
            cache.put(key, entry)
        timings.add(described.seconds)
        for phase, count in described.counts.items():
            timings.views[phase] += count
        done += described.counts["load views"]
        if progress:
            progress("real views (parse, describe)", done, len(ids))
    cache.record_view_keys(identity, keys)
    for stage in stages:
        if stage_key(stage) not in incomplete:
            cache.mark_complete(stage, identity)


def choose_members(val_scores: Mapping[str, np.ndarray], truth: np.ndarray, fuser: Fuser) -> list[str]:
    """Variants to fuse, chosen on the validation views: forward selection by fused MRR.

    Starts from the best single variant and adds, one at a time, the variant that raises
    the fused MRR most, while one does.
    """
    def mrr(labels: Sequence[str]) -> float:
        fused = fuser.fuse(np.stack([val_scores[label] for label in labels]))
        return float(np.mean(1.0 / truth_ranks(fused, truth)))

    chosen = [max(val_scores, key=lambda label: mrr([label]))]
    best = mrr(chosen)
    while True:
        gains = {label: mrr([*chosen, label]) for label in val_scores if label not in chosen}
        if not gains or max(gains.values()) <= best:
            return chosen
        label = max(gains, key=gains.__getitem__)
        chosen.append(label)
        best = gains[label]


def heading_offset_deg(a: float, b: float) -> float:
    return abs(math.degrees(math.atan2(math.sin(a - b), math.cos(a - b))))


def run_experiment(
    experiment: Experiment,
    dataset: Dataset,
    out: str | Path,
    *,
    progress: Progress | None = None,
    variant_progress: Callable[[str], None] | None = None,
    cache_root: str | Path | None = None,
    executor: Executor | None = None,
) -> tuple[Report, Timings]:
    """Train, score, fuse and evaluate every variant of ``experiment`` on ``dataset``.

    Real views are parsed and described first, once for every variant, in batches on the
    executor's workers; then every variant (and oracle row) trains and scores as one
    task. Results are the same whatever the executor and the number of workers.

    Args:
        progress: called with ``(phase, done, total)`` as each phase advances.
        variant_progress: called with each variant's label as it finishes.
        cache_root: folder of the feature cache (default ``out/cache``), shareable between runs.
        executor: where the work runs; default: the one the config's ``[execution]`` names,
            opened and closed here.
    """
    if executor is None:
        with open_executor(experiment.config.execution) as own:
            return run_experiment(
                experiment, dataset, out, progress=progress, variant_progress=variant_progress, cache_root=cache_root, executor=own
            )
    out = writable_folder(out)
    config = experiment.config
    timings = Timings()
    cache = FeatureCache(cache_root if cache_root is not None else out / "cache")
    views = Views(dataset, timings)
    with timings.phase("training plan"), timings.wall_phase("training plan"):
        plan = training_plan(dataset, config.training, views)
    with timings.wall_phase("real views (parse, describe)"):
        describe_real_views(experiment.variants, dataset, cache, executor, config.execution.batch, timings, progress)

    folders = folder_names(rv.label for rv in experiment.variants)
    # Absolute paths: a Ray worker does not run in this folder.
    root, cache_folder, out_folder = str(dataset.root.resolve()), str(cache.root.resolve()), out.resolve()  # type: ignore[union-attr]
    jobs = [
        VariantJob(rv, root, config.training, plan, str(out_folder / "variants" / folders[rv.label]), cache_folder)
        for rv in experiment.variants
    ]
    oracles = [rv for rv in experiment.variants if str(rv.variant) in config.ensemble.oracle and rv.variant.synthesizes]
    if oracles and _renderable(experiment):
        jobs += [
            VariantJob(rv, root, config.training, plan, str(out_folder / "oracle" / folders[rv.label]), cache_folder, experiment.workspace)
            for rv in oracles
        ]
    # Longest first, so that no worker is left with a long variant at the end: those that
    # synthesize (and the oracles, which render) before those that do not.
    jobs.sort(key=lambda job: not (job.oracle is not None or job.variant.variant.synthesizes))
    results: dict[str, VariantResult] = {}
    oracle_results: dict[str, VariantResult] = {}
    not_run: dict[str, str] = {}

    def keep(job: VariantJob, result: VariantResult) -> None:
        (oracle_results if job.oracle is not None else results)[job.variant.label] = result

    # Finished variants are read back here: a rerun starts no worker for them.
    todo = []
    for job in jobs:
        finished = finished_variant(job.variant, dataset, config.training, Path(job.folder), TrueRender.name if job.oracle else "")
        if finished is not None:
            keep(job, finished)
        else:
            todo.append(job)
    trained: list[tuple[VariantJob, Trained]] = []
    with timings.wall_phase("variants: training graphs, train"):
        ran = executor.map(train_variant, todo, describe=VariantJob.what, progress=(lambda d, n: progress("train the variants", d, n)) if progress else None)
        for job, outcome in zip(todo, ran):
            timings.add(outcome.timings)
            if outcome.trained is None:
                # A row whose checkpoint is not there is reported as such; the others still run.
                if job.oracle is None:
                    not_run[job.variant.label] = outcome.not_run
                    warn(f"{job.variant.label}: not run: {outcome.not_run.removeprefix('no weights: ')}")
                continue
            trained.append((job, outcome.trained))
            if variant_progress:
                variant_progress(f"{job.what()} trained")
    with timings.wall_phase("variants: score the query views"):
        scored = score_queries([t for _, t in trained], dataset, out, cache, executor, timings, progress)
    for (job, _), result in zip(trained, scored):
        keep(job, result)
    not_run = {rv.label: not_run[rv.label] for rv in experiment.variants if rv.label in not_run}  # in the config's order
    if not results:
        raise SsgaError(f"no variant could run: {'; '.join(not_run.values())}")

    tests, vals = dataset.split("test"), dataset.split("val")
    truth = np.array([s.place for s in tests])
    val_truth = np.array([s.place for s in vals])
    fuser = experiment.fuser.create()
    assert isinstance(fuser, Fuser)
    labels = [rv.label for rv in experiment.variants if rv.label in results]
    references: dict[str, np.ndarray] = {}
    best_single = None
    chosen = labels
    learned: dict[str, Any] = {}

    def fused(rule: Fuser, members: list[str]) -> np.ndarray:
        """The test views' fused scores; a learned rule is first fitted on the validation views."""
        if rule.learns:
            if not len(vals):
                raise SsgaError(f"fuser {rule.name!r} is learned on the validation views, but the workspace has none (protocol.val_per_class)")
            rule.fit(np.stack([results[label].val for label in members]), val_truth)
            learned[f"Ensemble ({rule.tag()})"] = {"members": members, **rule.learned()}
        return rule.fuse(np.stack([results[label].test for label in members]))

    if len(vals):
        val_scores = {label: results[label].val for label in labels}
        best_single = max(labels, key=lambda label: float(np.mean(1.0 / truth_ranks(val_scores[label], val_truth))))
        if not fuser.learns:  # a learned rule weighs its members itself (config validation says so)
            chosen = choose_members(val_scores, val_truth, fuser)
    ensemble_label = f"Ensemble ({fuser.tag()})"
    with timings.phase("evaluate"):
        fused_all = fused(fuser, labels)
        fused_chosen = fuser.fuse(np.stack([results[label].test for label in chosen])) if chosen != labels else fused_all
    selected_label = f"Ensemble ({fuser.tag()}) of {len(chosen)} chosen on validation: " + ", ".join(chosen)
    series = {selected_label: f"Ensemble ({fuser.tag()}) chosen on validation"}
    if config.ensemble.members == "validation" and len(vals):
        ensemble = (selected_label, fused_chosen)
        references[ensemble_label + " of all"] = fused_all
    else:
        ensemble = (ensemble_label, fused_all)
        if len(vals) and not fuser.learns:
            references[selected_label] = fused_chosen
    for also in experiment.also:
        rule = also.create()
        assert isinstance(rule, Fuser)
        with timings.phase("evaluate"):
            label = f"Ensemble ({rule.tag()}) of all" + (", learned on validation" if rule.learns else "")
            references[label] = fused(rule, labels)
        series[label] = f"Ensemble ({rule.tag()})"
    if learned:
        write_json(out / "fusion.json", learned)
    else:  # a rerun with no learned rule leaves no stale weights
        (out / "fusion.json").unlink(missing_ok=True)
    reference_variant = best_single or labels[0]
    references[f"nearest neighbour ({reference_variant})"] = results[reference_variant].nearest
    series[f"nearest neighbour ({reference_variant})"] = "nearest neighbour (best single)"

    for label in labels:  # the config's order, whichever finished first
        if label in oracle_results:
            references[f"oracle: {label} on true renders"] = oracle_results[label].test

    flags = {label: "training stopped at the epoch cap" for label in labels if results[label].training.get("stopped_at_cap")}
    for rv in experiment.variants:  # packaged weights meeting views unlike those they were trained on
        for stage in rv.stages.values():
            warning = issubclass(stage.cls, Learned) and stage.cls.out_of_domain(stage.config, experiment.workspace.name)
            if warning and rv.label in results:
                flags[rv.label] = "; ".join(filter(None, (flags.get(rv.label), warning)))
    landmark = {s.cell: s.pose.yaw for s in dataset.split("train")}
    near = np.array([heading_offset_deg(s.pose.yaw, landmark[s.cell]) <= 60.0 for s in tests])
    levels = np.array([s.level for s in tests])
    groups = {"L1": levels == 1, "L2": levels == 2, "L3": levels == 3, "near": near, "far": ~near}
    with timings.phase("evaluate"):
        report = Report.build(
            dataset.name,
            {label: results[label].test for label in labels},
            truth,
            groups=groups,
            num_classes=dataset.num_classes,
            ensemble=ensemble,
            best_single=best_single,
            references=references,
            flags=flags,
            not_run=not_run,
            series={label: name for label, name in series.items() if label in references or label == ensemble[0]},
        )
    with timings.phase("report"), timings.wall_phase("report"):
        atomic_write_bytes(out / "report.md", report.markdown().encode())
        atomic_write_bytes(out / "results.csv", report.csv().encode())
        atomic_write_bytes(out / "results.png", report.plot())
        rows = {**{label: results[label].test for label in labels}, ensemble[0]: ensemble[1]}
        save_predictions(out / "predictions.jsonl", tests, rows, truth, groups={"near": near, "far": ~near})
        # Each class is shown by its training view: the real one, or the render at its target
        # pose; a captured workspace has no such render, so its cell's real view stands in.
        real_of_cell = {s.cell: s for s in dataset.split("train")}
        class_views = {s.place: s if dataset.has_image(s) else real_of_cell[s.cell] for s in dataset.split("train") + dataset.split("target")}
        draw_queries(out / "queries", dataset, tests, ensemble[1], truth, class_views, n=config.ensemble.queries_to_draw)
        draw_for_the_page(experiment, dataset, cache, out)
        # The protocol values a build chose for this workspace (protocol.fit): part of what this run is.
        fitted = dataset.root / FITTED
        if fitted.exists():
            atomic_write_bytes(out / "protocol-fitted.json", fitted.read_bytes())
        else:
            (out / "protocol-fitted.json").unlink(missing_ok=True)
    write_json(out / "timings.json", timings.to_json())
    write_run_page(out)
    return report, timings


def draw_for_the_page(experiment: Experiment, dataset: Dataset, cache: FeatureCache, out: Path, views: int = 3) -> None:
    """The run page's pictures (``page.py``): the workspace map, test cameras by level, and the
    scene graphs of a few test views as the first variant with a parser cut them (its regions
    read back from the feature cache: nothing is parsed again)."""
    write_png(out / "workspace.png", birdseye(dataset, colour_by="level"))
    parsing = next((rv for rv in experiment.variants if "parser" in rv.stages), None)
    tests = dataset.split("test")
    if parsing is None or not tests:
        return
    keys = cache.view_keys(dataset_identity(dataset))
    samples = [tests[i] for i in np.linspace(0, len(tests) - 1, min(views, len(tests))).astype(int)]
    parser = parsing.stages["parser"]

    def stored(sample: Sample, view: View) -> Regions | None:
        return cache.stored_regions(parser, view, keys[sample.id]) if sample.id in keys else None

    scene_graph_pictures(dataset, stored, samples, out / "scene-graphs", title=parsing.label)


def _renderable(experiment: Experiment) -> bool:
    """Whether the experiment's workspace renders any pose (an oracle needs it)."""
    from ssga_bench.tasks import opened_workspace

    return isinstance(opened_workspace(experiment.workspace), Workspace)


def run(
    *,
    experiment: Experiment,
    output: Path | None = None,
    progress: Progress | None = None,
    variant_progress: Callable[[str], None] | None = None,
    executor: Executor | None = None,
) -> tuple[Report, Timings]:
    """Build (or reuse) the experiment's workspace, then train, score, fuse and report every variant.

    Args:
        output: the experiment folder; default the config's ``output``.
        progress, variant_progress: as for :func:`run_experiment`; the workspace
            build reports its phases (``plan``, ``render``) through ``progress`` too.
        executor: where the work runs (a bench shares one over its seeds); default: the
            one the config's ``[execution]`` names, opened and closed here.
    """
    if executor is None:
        with open_executor(experiment.config.execution) as own:
            return run(experiment=experiment, output=output, progress=progress, variant_progress=variant_progress, executor=own)
    output = writable_folder(output or experiment.config.output)
    timings = Timings()
    with timings.phase("workspace (plan + render)"), timings.wall_phase("workspace (plan + render)"):
        dataset = build_workspace(
            experiment.workspace, experiment.config.protocol, progress=progress, executor=executor, batch=experiment.config.execution.batch
        )
    report, ran = run_experiment(experiment, dataset, output, progress=progress, variant_progress=variant_progress, executor=executor)
    timings.add(ran)
    write_json(output / "timings.json", timings.to_json())
    write_run_page(output)  # again: the timings now hold the workspace's build
    return report, timings
