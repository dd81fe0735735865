"""Running an experiment: every variant trained and scored on a dataset, fused, reported.

For each variant:

1. **Training data.** Each cell's one real view gives a graph of its real class (the
   query path: P and D only). A variant with S also synthesizes, from that real view,
   ``synthetic_per_class`` graphs of every class of the cell: the class's training
   viewpoint (the synthesis target, or for the real class the real pose) and jittered
   copies of it. Variants without S have only the real graphs; each stands for every
   class of its cell (paper §4.1: they "simply use available training images as they
   are"), so they tell cells apart but not headings within a cell.
2. **Fit** the descriptor (a dictionary, a classifier) on the training views, real and
   synthetic, with their classes.
3. **Train** the variant's GCN, **score** every test view (query path).

Then the fuser combines the variants' class probabilities and every row is evaluated
per difficulty level (:mod:`ssga_core.evaluation`).

Outputs in the experiment folder: ``variants/<label>/`` (``gcn.pt``, ``scores.npy``,
``training.json``), ``report.md``, ``results.csv``, ``results.png``, ``timings.json``.
Each variant's outputs are keyed by a hash of everything they depend on, so a rerun
skips finished variants and an interrupted run resumes with the next one.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import re
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ssga_core.cache import FeatureCache
from ssga_core.config import Experiment, ResolvedVariant, TrainingConfig
from ssga_core.data import SceneGraph, View
from ssga_core.dataset import Dataset
from ssga_core.evaluation import Report
from ssga_core.gcn import load_gcn, save_gcn, train_gcn
from ssga_core.geometry import Pose
from ssga_core.io import atomic_write_bytes, read_json, write_json
from ssga_core.pipeline import BoundVariant, build_graph
from ssga_core.protocol import Sample
from ssga_core.stages import Fuser

Progress = Callable[[str, int, int], None]


@dataclass
class Timings:
    """Seconds spent per phase (parse, describe, synthesize, train, evaluate...)."""

    seconds: dict[str, float] = field(default_factory=lambda: defaultdict(float))

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - start

    def wrap(self, obj: object, method: str, phase: str) -> None:
        """Time every call of ``obj.method`` under ``phase`` (an instance attribute shadows the method)."""
        inner = getattr(obj, method)

        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.phase(phase):
                return inner(*args, **kwargs)

        setattr(obj, method, timed)


def instrument(bound: BoundVariant, timings: Timings) -> None:
    if bound.parser is not None:
        timings.wrap(bound.parser, "parse", "parse")
    for method in ("extract", "pool", "describe", "fit"):
        if hasattr(bound.descriptor, method):
            timings.wrap(bound.descriptor, method, "describe" if method != "fit" else "fit descriptor")
    if bound.synthesizer is not None:
        timings.wrap(bound.synthesizer, "synthesize", "synthesize")


def jittered(pose: Pose, rng: np.random.Generator, metres: float, degrees: float) -> Pose:
    r, phi = metres * math.sqrt(rng.random()), rng.random() * 2 * math.pi
    yaw = pose.yaw + math.radians(degrees) * (2 * rng.random() - 1)
    return Pose(pose.x + r * math.cos(phi), pose.y + r * math.sin(phi), yaw, pose.height)


def training_poses(dataset: Dataset, config: TrainingConfig) -> list[tuple[Sample, Pose, int]]:
    """``(real sample, pose to synthesize, class)`` for every synthetic training graph, seeded."""
    rng = np.random.default_rng(config.seed)
    real_of_cell = {s.cell: s for s in dataset.split("train")}
    out = []
    for s in sorted(dataset.split("train") + dataset.split("target"), key=lambda s: s.place):
        real = real_of_cell[s.cell]
        # A target class gets its target and n - 1 jittered copies; the real class has its
        # real graph already, and gets n - 1 jittered syntheses beside it.
        first = [] if s.split == "train" else [s.pose]
        poses = first + [jittered(s.pose, rng, config.jitter_m, config.jitter_deg) for _ in range(config.synthetic_per_class - 1)]
        out.extend((real, p, s.place) for p in poses)
    return out


def slug(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", label).strip("_") or "variant"


def variant_key(rv: ResolvedVariant, training: TrainingConfig, dataset: Dataset) -> str:
    spec = {
        "variant": str(rv.variant),
        "stages": {k: [s.cls.name, s.config.model_dump(mode="json")] for k, s in sorted(rv.stages.items())},
        "training": training.model_dump(mode="json"),
        "dataset": dataset.header,
        "plan": hashlib.blake2b((dataset.root / "plan.json").read_bytes(), digest_size=8).hexdigest(),
    }
    return hashlib.blake2b(json.dumps(spec, sort_keys=True).encode(), digest_size=10).hexdigest()


class Views:
    """Loads dataset views, keeping the few real training views in memory."""

    def __init__(self, dataset: Dataset, timings: Timings) -> None:
        self.dataset, self.timings = dataset, timings
        self._kept: dict[str, View] = {}

    def __call__(self, sample: Sample, keep: bool = False) -> View:
        if sample.id in self._kept:
            return self._kept[sample.id]
        with self.timings.phase("load views"):
            view = self.dataset.view(sample)
        if keep:
            self._kept[sample.id] = view
        return view


def run_variant(
    rv: ResolvedVariant,
    dataset: Dataset,
    training: TrainingConfig,
    folder: Path,
    cache: FeatureCache,
    views: Views,
    timings: Timings,
    progress: Progress | None = None,
) -> np.ndarray:
    """Train and score one variant; returns ``(test views, classes)`` probabilities."""
    key = variant_key(rv, training, dataset)
    scores_path, meta_path = folder / "scores.npy", folder / "training.json"
    if scores_path.exists() and meta_path.exists() and read_json(meta_path).get("key") == key:
        return np.load(scores_path)

    bound = rv.bind()
    instrument(bound, timings)
    reals = {s.cell: s for s in dataset.split("train")}
    graphs: list[SceneGraph] = []
    labels: list[int] = []
    synthetic = training_poses(dataset, training) if bound.variant.synthesizes else []
    fit_views = [views(s, keep=True) for s in reals.values()]
    fit_labels = [s.place for s in reals.values()]
    if synthetic:
        # The descriptor learns from the synthetic views too, as the GCN will see them.
        for real, pose, place in synthetic[:: training.synthetic_per_class]:
            fit_views.append(bound.synthesizer.synthesize(views(real, keep=True), pose).view)  # type: ignore[union-attr]
            fit_labels.append(place)
    bound.descriptor.fit(fit_views, fit_labels)
    orientations = dataset.plan.config.orientations
    for s in reals.values():
        graph = build_graph(bound, views(s, keep=True), cache=cache)
        # Without S, the real graph is all a cell has: it stands for each of the cell's classes.
        stands_for = [s.place]
        if not bound.variant.synthesizes and training.real_for_every_class:
            first = s.place - s.place % orientations
            stands_for = list(range(first, first + orientations))
        graphs.extend([graph] * len(stands_for))
        labels.extend(stands_for)
    for n, (real, pose, place) in enumerate(synthetic, 1):
        graphs.append(build_graph(bound, views(real, keep=True), pose, cache=cache))
        labels.append(place)
        if progress:
            progress("training graphs", n, len(synthetic))
    with timings.phase("train"):
        model, report = train_gcn(graphs, np.array(labels), dataset.num_classes, training)
    save_gcn(model, folder / "gcn.pt")

    tests = dataset.split("test")
    test_graphs = []
    for n, s in enumerate(tests, 1):
        test_graphs.append(build_graph(bound, views(s), cache=cache))
        if progress:
            progress("test graphs", n, len(tests))
    with timings.phase("evaluate"):
        scores = load_gcn(folder / "gcn.pt").predict(test_graphs)
    atomic_write_bytes(scores_path, _npy_bytes(scores))
    write_json(meta_path, {"key": key, "label": rv.label, "graphs": len(graphs), **asdict(report)})
    return scores


def _npy_bytes(array: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.save(out, array)
    return out.getvalue()


def run_experiment(
    experiment: Experiment,
    dataset: Dataset,
    out: str | Path,
    *,
    progress: Progress | None = None,
    variant_progress: Callable[[str], None] | None = None,
    cache_root: str | Path | None = None,
) -> tuple[Report, Timings]:
    """Train, score, fuse and evaluate every variant of ``experiment`` on ``dataset``.

    Args:
        progress: called with ``(phase, done, total)`` within a variant.
        variant_progress: called with each variant's label as it starts.
        cache_root: folder of the feature cache (default ``out/cache``), shareable between runs.
    """
    out = Path(out)
    timings = Timings()
    cache = FeatureCache(cache_root if cache_root is not None else out / "cache")
    views = Views(dataset, timings)
    scores: dict[str, np.ndarray] = {}
    for rv in experiment.variants:
        if variant_progress:
            variant_progress(rv.label)
        scores[rv.label] = run_variant(rv, dataset, experiment.config.training, out / "variants" / slug(rv.label), cache, views, timings, progress)
    fuser = experiment.fuser.create()
    assert isinstance(fuser, Fuser)
    tests = dataset.split("test")
    truth = np.array([s.place for s in tests])
    levels = np.array([s.level for s in tests])
    with timings.phase("evaluate"):
        fused = fuser.fuse(np.stack([scores[rv.label] for rv in experiment.variants]))
        report = Report.build(dataset.name, scores, f"Ensemble ({fuser.tag()})", fused, truth, levels, dataset.num_classes)
    atomic_write_bytes(out / "report.md", report.markdown().encode())
    atomic_write_bytes(out / "results.csv", report.csv().encode())
    atomic_write_bytes(out / "results.png", report.plot())
    write_json(out / "timings.json", dict(timings.seconds))
    return report, timings
