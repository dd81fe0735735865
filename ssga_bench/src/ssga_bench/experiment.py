"""Running an experiment: every variant trained and scored on a dataset, fused, reported.

For each variant:

1. **Training graphs.** This module draws, per cell, the poses of every class's
   pseudo-training graphs (the class's training viewpoint and ``synthetic_per_class - 1``
   jittered copies, :func:`training_cells`); the pipeline
   (:func:`ssga_core.pipeline.training_graphs`) fits the descriptor and builds the
   graphs as the variant's order says, synthesizing or not. The runner never branches
   on the order and never calls a stage itself.
2. **Train** the variant's GCN, **score** every test view (the query path,
   :func:`ssga_core.pipeline.build_graph`).

Then the fuser combines the variants' class probabilities and every row is evaluated
per difficulty level (:mod:`ssga_bench.evaluation`).

Outputs in the experiment folder: ``variants/<label>/`` (``gcn.pt``, ``scores.npy``,
``training.json``), ``report.md``, ``results.csv``, ``results.png``, ``timings.json``.
Each variant's outputs are keyed by a hash of everything they depend on, so a rerun
skips finished variants and an interrupted run resumes with the next one.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ssga_bench.cache import FeatureCache
from ssga_bench.config import Experiment, TrainingConfig
from ssga_bench.dataset import Dataset, build_workspace
from ssga_bench.evaluation import Report
from ssga_bench.protocol import Sample
from ssga_bench.gcn import load_gcn, save_gcn, train_gcn
from ssga_bench.io import atomic_write_bytes, load_npy, npy_bytes, read_json, warn, writable_folder, write_json
from ssga_core.data import View
from ssga_core.errors import SsgaError
from ssga_core.config import ResolvedVariant
from ssga_core.geometry import Pose
from ssga_core.pipeline import BoundVariant, CellTraining, Progress, build_graph, training_graphs
from ssga_core.stages import Fuser



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


def training_cells(dataset: Dataset, config: TrainingConfig, views: Views) -> list[CellTraining]:
    """Each cell's real view and the poses of every class's pseudo-training graphs, seeded.

    A target class gets its training viewpoint and ``synthetic_per_class - 1``
    jittered copies; the real class has its real view already, and gets the
    jittered copies beside it. Jitters are drawn class by class.
    """
    rng = np.random.default_rng(config.seed)
    poses: dict[int, dict[int, list[Pose]]] = defaultdict(dict)
    for s in sorted(dataset.split("train") + dataset.split("target"), key=lambda s: s.place):
        first = [] if s.split == "train" else [s.pose]
        jitters = [jittered(s.pose, rng, config.jitter_m, config.jitter_deg) for _ in range(config.synthetic_per_class - 1)]
        poses[s.cell][s.place] = first + jitters
    return [CellTraining(views(s, keep=True), s.place, poses[s.cell]) for s in dataset.split("train")]


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
    finished = _finished_scores(folder, key, (len(dataset.split("test")), dataset.num_classes))
    if finished is not None:
        return finished

    bound = rv.bind()
    instrument(bound, timings)
    cells = training_cells(dataset, training, views)
    graphs, labels = training_graphs(bound, cells, real_for_every_class=training.real_for_every_class, memo=cache, progress=progress)
    with timings.phase("train"):
        model, report = train_gcn(graphs, np.array(labels), dataset.num_classes, training)
    save_gcn(model, folder / "gcn.pt")

    tests = dataset.split("test")
    test_graphs = []
    for n, s in enumerate(tests, 1):
        test_graphs.append(build_graph(bound, views(s), memo=cache))
        if progress:
            progress("test graphs", n, len(tests))
    with timings.phase("evaluate"):
        scores = load_gcn(folder / "gcn.pt").predict(test_graphs)
    atomic_write_bytes(scores_path, npy_bytes(scores))
    write_json(meta_path, {"key": key, "label": rv.label, "graphs": len(graphs), **asdict(report)})
    return scores


def _finished_scores(folder: Path, key: str, shape: tuple[int, int]) -> np.ndarray | None:
    """The scores a finished run of this variant left, or None; damaged ones are recomputed, with a warning."""
    scores_path, meta_path = folder / "scores.npy", folder / "training.json"
    if not (scores_path.exists() and meta_path.exists()):
        return None
    try:
        if read_json(meta_path).get("key") != key:
            return None
    except (SsgaError, AttributeError):
        warn(f"{meta_path}: damaged; training this variant again")
        return None
    return load_npy(scores_path, shape, what="scores")


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
    out = writable_folder(out)
    timings = Timings()
    cache = FeatureCache(cache_root if cache_root is not None else out / "cache")
    views = Views(dataset, timings)
    scores: dict[str, np.ndarray] = {}
    folders = folder_names(rv.label for rv in experiment.variants)
    for rv in experiment.variants:
        if variant_progress:
            variant_progress(rv.label)
        folder = out / "variants" / folders[rv.label]
        scores[rv.label] = run_variant(rv, dataset, experiment.config.training, folder, cache, views, timings, progress)
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


def run(
    *,
    experiment: Experiment,
    output: Path | None = None,
    progress: Progress | None = None,
    variant_progress: Callable[[str], None] | None = None,
) -> tuple[Report, Timings]:
    """Build (or reuse) the experiment's workspace, then train, score, fuse and report every variant.

    Args:
        output: the experiment folder; default the config's ``output``.
        progress, variant_progress: as for :func:`run_experiment`; the workspace
            build reports its phases (``plan``, ``render``) through ``progress`` too.
    """
    output = writable_folder(output or experiment.config.output)
    timings = Timings()
    with timings.phase("workspace (plan + render)"):
        dataset = build_workspace(experiment.workspace, experiment.config.protocol, progress=progress)
    report, ran = run_experiment(experiment, dataset, output, progress=progress, variant_progress=variant_progress)
    for phase, seconds in ran.seconds.items():
        timings.seconds[phase] += seconds
    return report, timings
