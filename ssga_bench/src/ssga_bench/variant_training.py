"""One variant's training, as the task a worker runs (:func:`train_variant`): its training
graphs, its descriptor fitted, its classifier (the GCN or graph matching) trained, all left
in its folder under a key of everything they depend on, so a rerun finds a finished
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
from ssga_bench.gcn import load_gcn, save_gcn, train_gcn
from ssga_bench.io import atomic_write_bytes, load_npy, load_npz, npz_bytes, read_json, warn, write_json
from ssga_bench.matching import GraphMatcher
from ssga_bench.oracle import TrueRender
from ssga_bench.timings import Timings, instrument
from ssga_bench.training_plan import TrainingPlan, Views
from ssga_core.config import ResolvedStage, ResolvedVariant
from ssga_core.data import SceneGraph
from ssga_core.errors import MissingWeightsError, PluginError, SsgaError
from ssga_core.pipeline import Progress, training_graphs
from ssga_core.stages import Descriptor, Synthesizer


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
        "variant": str(rv.variant),
        "stages": {k: [s.cls.name, s.config.model_dump(mode="json")] for k, s in sorted(rv.stages.items())},
        "training": training.model_dump(mode="json"),
        "dataset": dataset.header,
        "plan": hashlib.blake2b((dataset.root / "plan.json").read_bytes(), digest_size=8).hexdigest(),
    }
    return hashlib.blake2b(json.dumps(spec, sort_keys=True).encode(), digest_size=10).hexdigest()


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
    for file in SCORE_FILES.values():
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
        rule = {
            "match_whole": training.match_whole,
            "match_layout": training.match_layout,
            "layout_sigma": training.layout_sigma,
            "match_standardise": training.match_standardise,
        }
        matcher = GraphMatcher.of(
            graphs,
            labels,
            num_classes,
            training.match_whole,
            training.match_layout,
            training.layout_sigma,
            training.match_standardise,
        )
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
