"""One variant's training, as the tasks workers run: its descriptor fitted and its real
graphs built (:func:`prepare_variant`, one task per variant), the graphs of its
pseudo-views (:func:`pseudo_graphs`, in chunks of pseudo-views, each chunk through every
prepared variant, so that a machine with more cores than variants keeps them busy), then
its classifier, the GCN or graph matching (:func:`finish_variant`). All of it is left in the
variant's folder under a key of everything it depends on, so a rerun finds a finished
variant (:func:`finished_variant`) or a trained one (:class:`Trained`) and does not train
it again."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ssga_bench.bow import normalise_rows
from ssga_bench.cache import FeatureCache
from ssga_bench.config import TrainingConfig
from ssga_bench.dataset import Dataset
from ssga_bench.execution import memo
from ssga_bench.seeds import DRAWS
from ssga_bench.gcn import load_gcn, save_gcn, train_gcn
from ssga_bench.io import atomic_write_bytes, load_npy, load_npz, npz_bytes, read_json, warn, write_json
from ssga_bench.matching import GraphMatcher
from ssga_bench.oracle import TrueRender
from ssga_bench.timings import Timings, instrument
from ssga_bench.training_plan import TrainingPlan, Views, training_cells
from ssga_core.config import ResolvedStage, ResolvedVariant
from ssga_core.data import SceneGraph
from ssga_core.errors import MissingWeightsError, PluginError, SsgaError
from ssga_core.pipeline import (
    BoundVariant,
    PseudoView,
    fit_training_descriptor,
    pseudo_training_graph,
    real_training_graphs,
)
from ssga_core.stages import Descriptor


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


SCORE_FILES = {"test": "scores.npy", "nearest": "nn_scores.npy", "val": "val_scores.npy"}
"""Each score array of a :class:`VariantResult` and its file in the variant's folder."""
_TRAINED = ("descriptor.npz", "nearest.npz")
"""What a trained variant's folder holds for the scoring tasks, besides ``training.json`` and its classifier."""
CLASSIFIER_FILES = {"gcn": "gcn.pt", "graph-match": "matcher.npz"}
"""Each ``[training] classifier``'s file in a trained variant's folder."""


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


def variant_key(rv: ResolvedVariant, training: TrainingConfig, dataset: Dataset, extra: str = "") -> str:
    spec = {
        "extra": extra,
        "draws": DRAWS,
        "variant": str(rv.variant),
        "stages": {k: [s.cls.name, s.config.model_dump(mode="json", exclude=s.config.unkeyed())] for k, s in sorted(rv.stages.items())},
        "training": training.model_dump(mode="json", exclude=_unused_options(rv, training) | _unused_match_settings(rv, training) | training.unkeyed()),
        "dataset": dataset.header,
        "plan": hashlib.blake2b((dataset.root / "plan.json").read_bytes(), digest_size=8).hexdigest(),
    }
    return hashlib.blake2b(json.dumps(spec, sort_keys=True).encode(), digest_size=10).hexdigest()


PIPELINE_OPTIONS = ("parse_invented", "describe_invented", "join_split_parts")
"""The training settings that are the pipeline's own (``BoundVariant`` fields): what becomes of S's
drawing where no source reached, and of the parts it split."""

_KEYED_WHEN_OFF = frozenset({"parse_invented"})
"""The options that were keyed before the others existed: the others are left out of a variant's key
while off, so that the runs made before them keep their keys and resume."""


def pipeline_options(training: TrainingConfig) -> tuple[tuple[str, bool], ...]:
    """:data:`PIPELINE_OPTIONS` with their values in ``training``."""
    return tuple((name, getattr(training, name)) for name in PIPELINE_OPTIONS)


def _unused_options(rv: ResolvedVariant, training: TrainingConfig) -> set[str]:
    """Pipeline options left out of a variant's key: one that cannot change its graphs, so that trying
    it reuses the other variants; and those of :data:`_KEYED_WHEN_OFF`'s complement while off."""
    parser = rv.stages.get("parser")
    applies = {
        "parse_invented": rv.variant.describes_carried_parts,
        "describe_invented": rv.variant.describes_before_synthesis,
        "join_split_parts": rv.variant.carries_parts and parser is not None and parser.cls.regions_are_category_pieces,
    }
    return {name for name, on in pipeline_options(training) if not applies[name] or (name not in _KEYED_WHEN_OFF and not on)}


WHITENING = ("match_whiten", "match_whiten_parts", "match_whiten_variants")
"""The settings of graph matching's within-class whitening (whole images, parts, which variants)."""


def whitens(rv: ResolvedVariant, training: TrainingConfig) -> bool:
    """Whether graph matching whitens this variant's features (``match_whiten``, ``match_whiten_variants``)."""
    return training.match_whiten is not None and (training.match_whiten_variants == "all" or rv.variant.describes_synthesized_views)


def _unused_match_settings(rv: ResolvedVariant, training: TrainingConfig) -> set[str]:
    """Graph-matching settings left out of the key of a variant they cannot change, so that trying one retrains only
    the variants it changes: the whitening where ``match_whiten_variants`` leaves the variant plain, the category
    penalty where its parser names no categories (``Parser.names_categories``) or it has none, and its score floor
    where there is no penalty."""
    unused = set(WHITENING) if training.match_whiten is not None and not whitens(rv, training) else set()
    parser = rv.stages.get("parser")
    if parser is None or not parser.cls.names_categories:
        unused.add("match_category_penalty")
    if "match_category_penalty" in unused or not training.match_category_penalty:
        unused.add("match_category_min_score")
    return unused


def carried_part_groups(graphs: Sequence[SceneGraph], labels: Sequence[int], sources: Sequence[Sequence[int]]) -> np.ndarray | None:
    """``(training parts,)``: each part of ``graphs`` (nodes 1.. of each, graph after graph) numbered by the real part it
    is within its class, (class, cell, region of that cell's real view), from ``SceneGraph.part_origins``; -1 for a part
    parsed on a synthetic view. ``sources``: per graph, the cells of the real views it was built from (its own cell for
    a real graph, ``PseudoView.sources`` for a pseudo-view's). None where no real part is in two graphs of its class
    (a variant that parses the synthetic views, SPD, has only its real views' parts)."""
    numbers: dict[tuple[int, int, int], int] = {}
    out: list[int] = []
    for graph, label, cells in zip(graphs, labels, sources, strict=True):
        if graph.part_origins is None:
            out.extend([-1] * graph.num_parts)
            continue
        for source, region in graph.part_origins[1:].tolist():
            out.append(-1 if source < 0 else numbers.setdefault((int(label), int(cells[source]), region), len(numbers)))
    groups = np.asarray(out, np.int64)
    return groups if numbers and np.bincount(groups[groups >= 0]).max() > 1 else None


def _fit_classifier(
    graphs: Sequence[SceneGraph],
    labels: Sequence[int],
    groups: np.ndarray,
    num_classes: int,
    training: TrainingConfig,
    folder: Path,
    part_groups: np.ndarray | None = None,
) -> dict[str, Any]:
    """Fit the variant's classifier (``training.classifier``, its whitening already settled for the variant: :func:`whitens`)
    and save it in ``folder``; returns its training record. ``part_groups``: :func:`carried_part_groups`, for
    ``match_whiten_parts = "carried"``."""
    if training.classifier == "graph-match":
        rule = {
            "match_whole": training.match_whole,
            "match_layout": training.match_layout,
            "layout_sigma": training.layout_sigma,
            "match_standardise": training.match_standardise,
            "match_drawn": training.match_drawn,
            "match_drawn_prior": training.match_drawn_prior,
            "match_burst": training.match_burst,
            "match_burst_power": training.match_burst_power,
            **({} if training.match_whiten is None else {"match_whiten": training.match_whiten, "match_whiten_parts": training.match_whiten_parts}),
        }
        matcher = GraphMatcher.of(
            graphs,
            labels,
            num_classes,
            training.match_whole,
            training.match_layout,
            training.layout_sigma,
            training.match_standardise,
            training.match_drawn,
            training.match_drawn_prior,
            training.match_burst,
            training.match_burst_power,
            training.match_whiten,
            bool(training.match_whiten_parts),
            part_groups if training.match_whiten_parts == "carried" else None,
            training.match_category_penalty,
            training.match_category_min_score,
        )
        if matcher.category_penalty:  # recorded where it acts: graphs whose parser names no categories match without it
            rule["match_category_penalty"] = matcher.category_penalty
            if matcher.category_min_score:
                rule["match_category_min_score"] = matcher.category_min_score
        atomic_write_bytes(folder / CLASSIFIER_FILES["graph-match"], npz_bytes(matcher.state_dict()))
        return rule
    model, report = train_gcn(graphs, np.array(labels), num_classes, training, groups=groups)
    save_gcn(model, folder / CLASSIFIER_FILES["gcn"])
    return asdict(report)


def load_classifier(folder: Path, kind: str) -> Any:
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


def finished_variant(rv: ResolvedVariant, dataset: Dataset, training: TrainingConfig, folder: Path, extra: str = "") -> VariantResult | None:
    """What a finished run of this variant left in ``folder`` (``extra``: the oracle's synthesizer), or None."""
    key = variant_key(rv, training, dataset, extra=extra)
    shapes = {"test": len(dataset.split("test")), "nearest": len(dataset.split("test")), "val": len(dataset.split("val"))}
    return _finished(folder, key, {k: (n, dataset.num_classes) for k, n in shapes.items()})


def _finished(folder: Path, key: str, shapes: dict[str, tuple[int, int]]) -> VariantResult | None:
    """What a finished run of this variant left, or None; damaged outputs are recomputed, with a warning."""
    meta_path = folder / "training.json"
    if not (meta_path.exists() and all((folder / f).exists() for f in SCORE_FILES.values())):
        return None
    try:
        meta = read_json(meta_path)
        if meta.get("key") != key:
            return None
    except (SsgaError, AttributeError):
        warn(f"{meta_path}: damaged; training this variant again")
        return None
    arrays = {name: load_npy(folder / file, shapes[name], what="scores") for name, file in SCORE_FILES.items()}
    if any(a is None for a in arrays.values()):
        return None
    return VariantResult(training=meta, **arrays)


@dataclass(frozen=True)
class VariantJob:
    """One variant to train, as the per-variant tasks (:func:`prepare_variant`, :func:`finish_variant`) ship it to a worker.

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
    """What :func:`finish_variant` sends back: the trained variant, and its timings."""

    trained: Trained
    timings: Timings


@dataclass(frozen=True)
class Prepared:
    """A variant with its descriptor fitted (its state in ``descriptor.npz``) and its real
    graphs built; left to do: its pseudo-views' graphs (:func:`pseudo_graphs`) and its
    classifier (:func:`finish_variant`).

    It does not carry its :class:`VariantJob` back: the driver has it, and the job holds the
    training plan with every real view.

    Attributes:
        graphs, labels: the real graphs and their classes
            (:func:`~ssga_core.pipeline.real_training_graphs`).
        fitting: the graphs of the pseudo-views the descriptor was fitted on, by index into
            the plan's pseudo-views (built where they were rendered, so none is rendered twice).
    """

    key: str
    label: str
    graphs: list[SceneGraph]
    labels: list[int]
    fitting: dict[int, SceneGraph]


@dataclass(frozen=True)
class PrepareOutcome:
    """What :func:`prepare_variant` sends back: the variant trained before, or prepared, or
    why it could not run; and its timings."""

    trained: Trained | None
    prepared: Prepared | None
    not_run: str
    timings: Timings


def prepare_variant(job: VariantJob) -> PrepareOutcome:
    """Fit the variant's descriptor and build its real graphs (a variant trained before with
    the same key is only read back); a missing checkpoint is an outcome, not a failure."""
    from ssga_bench.tasks import opened_dataset

    timings = Timings()
    dataset = opened_dataset(job.dataset)
    folder = Path(job.folder)
    key = variant_key(job.variant, job.training, dataset, extra=TrueRender.name if job.oracle is not None else "")
    trained = _trained(job.variant, folder, key)
    if trained is not None:
        return PrepareOutcome(trained, None, "", timings)
    # Scores of an earlier training (another key) must not pass for this one's.
    for file in SCORE_FILES.values():
        (folder / file).unlink(missing_ok=True)
    cache = memo(("feature cache", job.cache), lambda: FeatureCache(job.cache))
    plan = job.plan
    try:
        # Every stage runs here (a learned one may load its checkpoint only when first used),
        # so a missing checkpoint shows here, not in the chunks.
        bound = _bind(job.variant, job.oracle, pipeline_options(job.training))
        instrument(bound, timings)
        first = fit_training_descriptor(bound, plan.cells, plan.pseudo)
        graphs, labels = real_training_graphs(bound, plan.cells, real_for_every_class=job.training.real_for_every_class, memo=cache)
        fitting = {i: pseudo_training_graph(bound, plan.cells, plan.pseudo[i], cache, synthesis=syn) for i, syn in first.items()}
    except MissingWeightsError as exc:
        return PrepareOutcome(None, None, f"no weights: {exc}", timings)
    atomic_write_bytes(folder / "descriptor.npz", npz_bytes(fitted_state(bound.descriptor)))
    return PrepareOutcome(None, Prepared(key, bound.label, graphs, labels, fitting), "", timings)


def _bind(variant: ResolvedVariant, oracle: ResolvedStage | None, options: tuple[tuple[str, bool], ...] = ()) -> BoundVariant:
    """The variant's stages; the oracle's true renders in place of its synthesizer."""
    from ssga_bench.tasks import opened_workspace

    bound = dataclasses.replace(variant.bind(), **dict(options))
    if oracle is not None:
        synthesizer = TrueRender(opened_workspace(oracle))
        bound = dataclasses.replace(bound, synthesizer=synthesizer, label=f"{bound.label} on {synthesizer.name}s")
    return bound


def fitted_stages(
    variant: ResolvedVariant, folder: str | Path, oracle: ResolvedStage | None = None, options: tuple[tuple[str, bool], ...] = ()
) -> BoundVariant:
    """The variant's stages in another process, its descriptor as fitted: the state
    :func:`prepare_variant` left in ``folder / "descriptor.npz"``."""
    bound = _bind(variant, oracle, options)
    bound.descriptor.load_state_dict(load_npz(Path(folder) / "descriptor.npz"))
    return bound


PSEUDO_CHUNK = 16
"""Pseudo-views per training-graph task (:func:`pseudo_graphs`). Each goes through every
variant, so a chunk is a few seconds of work: small enough for every worker to get its
share of a run's pseudo-views (288 in the `demo`, 1,440 in the `bench` preset). A fixed
cut, though the graphs would not depend on it."""


@dataclass(frozen=True)
class FittedVariant:
    """A prepared variant as a chunk task opens it: its stages, with the descriptor its
    ``descriptor.npz`` holds (``key``: that file's training, so a worker opens it once)."""

    variant: ResolvedVariant
    folder: str
    key: str
    oracle: ResolvedStage | None
    options: tuple[tuple[str, bool], ...] = ()
    """:func:`pipeline_options` of the run's training."""


@dataclass(frozen=True)
class PseudoChunk:
    """A chunk of the plan's pseudo-views (with their indices), to build under every variant."""

    dataset: str
    cache: str
    variants: tuple[FittedVariant, ...]
    pseudo: tuple[tuple[int, PseudoView], ...]

    def what(self) -> str:
        first, last = self.pseudo[0][0], self.pseudo[-1][0]
        return f"training graphs of pseudo-views {first}-{last}" if last != first else f"training graph of pseudo-view {first}"


@dataclass(frozen=True)
class ChunkGraphs:
    """What :func:`pseudo_graphs` sends back: per variant, the chunk's graphs in its order; its timings."""

    graphs: tuple[tuple[SceneGraph, ...], ...]
    timings: Timings


def pseudo_graphs(chunk: PseudoChunk) -> ChunkGraphs:
    """The training graphs of a chunk of pseudo-views under every variant.

    The variants are opened once per worker. Each pseudo-view goes through every variant
    in turn, so that what they compute of the same synthetic view (SD, SPD and DSP render
    the same one) is computed once (the feature cache).
    """
    from ssga_bench.tasks import opened_dataset

    dataset = opened_dataset(chunk.dataset)
    cache = memo(("feature cache", chunk.cache), lambda: FeatureCache(chunk.cache))
    # Keyed by the dataset object too (the entry keeps it alive): a dataset rebuilt in place is another.
    _, cells = memo(("training cells", chunk.dataset, id(dataset)), lambda: (dataset, training_cells(dataset, Views(dataset, Timings()))))

    def open_all() -> tuple[Timings, list[BoundVariant]]:
        timings = Timings()
        bounds = []
        for v in chunk.variants:
            bound = fitted_stages(v.variant, v.folder, v.oracle, v.options)
            instrument(bound, timings)
            bounds.append(bound)
        return timings, bounds

    timings, bounds = memo(("fitted variants", tuple((v.folder, v.key) for v in chunk.variants)), open_all)
    timings.clear()
    graphs: list[list[SceneGraph]] = [[] for _ in bounds]
    for _, p in chunk.pseudo:
        for bound, built in zip(bounds, graphs):
            built.append(pseudo_training_graph(bound, cells, p, cache))
    return ChunkGraphs(tuple(tuple(g) for g in graphs), timings.take())


@dataclass(frozen=True)
class FinishJob:
    """A prepared variant and the graphs of all its pseudo-views, in the plan's order (none without S)."""

    job: VariantJob
    prepared: Prepared
    pseudo: list[SceneGraph]

    def what(self) -> str:
        return self.job.what()


def finish_variant(job: FinishJob) -> VariantOutcome:
    """Fit the variant's classifier on all its training graphs and leave it in its folder."""
    from ssga_bench.tasks import opened_dataset

    timings = Timings()
    prepared, variant_job = job.prepared, job.job
    dataset = opened_dataset(variant_job.dataset)
    folder = Path(variant_job.folder)
    plan = variant_job.plan
    graphs = [*prepared.graphs, *job.pseudo]
    labels = [*prepared.labels, *(p.place for p in plan.pseudo)] if job.pseudo else list(prepared.labels)
    groups = plan.groups(len(prepared.graphs), bool(job.pseudo))
    part_groups = None
    if job.pseudo and variant_job.training.match_whiten_parts == "carried":
        # With S each cell's real view is one graph, in the plan's order (real_training_graphs).
        sources = [(cell,) for cell in range(len(prepared.graphs))] + [p.sources for p in plan.pseudo]
        part_groups = carried_part_groups(graphs, labels, sources)
    with timings.phase("train"):
        training = variant_job.training
        if not whitens(variant_job.variant, training):
            training = training.model_copy(update={"match_whiten": None})
        fitted = _fit_classifier(graphs, labels, groups, dataset.num_classes, training, folder, part_groups)
    atomic_write_bytes(folder / "nearest.npz", npz_bytes({"features": whole_image_features(graphs), "labels": np.asarray(labels, np.int64)}))
    record = {"key": prepared.key, "label": prepared.label, "graphs": len(graphs), "classifier": variant_job.training.classifier, **fitted}
    write_json(folder / "training.json", record)  # last: the folder is a trained variant once it is there
    return VariantOutcome(Trained(variant_job.variant, str(folder), prepared.key, record), timings)
