"""Running an experiment: every variant trained and scored on a dataset, fused, reported.

For each variant:

1. **Training graphs.** The runner draws, per cell, the poses of every class's
   pseudo-training graphs (the class's training viewpoint and ``synthetic_per_class - 1``
   jittered copies, :func:`~ssga_bench.training_plan.training_plan`); the pipeline
   (:func:`ssga_core.pipeline.training_graphs`) fits the descriptor and builds the
   graphs as the variant's order says, synthesizing or not. The runner never branches
   on the order and never calls a stage itself.
2. **Train** the variant's classifier, the GCN or graph matching. The work is cut so that
   every worker has some: the descriptors are fitted and the real graphs built one task
   per variant (:func:`prepare_variant`), the pseudo-views' graphs in chunks, each chunk
   through every variant (:func:`pseudo_graphs`), the classifiers one task per variant
   (:func:`finish_variant`). Then
   **score** every test and validation view (the query path,
   :func:`ssga_core.pipeline.build_graph`) in chunks, each chunk through every trained
   variant (:func:`score_chunk`).

Then the fuser combines the variants' class probabilities (:mod:`ssga_bench.fusion`) and
every row is evaluated per difficulty level (:mod:`ssga_bench.evaluation`) and reported
(:mod:`ssga_bench.run_report`).

This module drives the run: it maps the tasks on the executor (the training of a variant,
:mod:`ssga_bench.variant_training`; the scoring of a chunk of views,
:mod:`ssga_bench.scoring`; describing the real views, :mod:`ssga_bench.tasks`), keeps
what they return and writes the variants' score files.

Outputs in the experiment folder: ``variants/<label>/`` (``gcn.pt`` or ``matcher.npz``,
``descriptor.npz``, ``nearest.npz``, ``training.json``, ``scores.npy``...),
``report.md``, ``results.csv``, ``results.png``, ``timings.json`` (and ``heading.json``, the
heading prior's record, where ``[prior]`` asks for one). Each variant's
outputs are keyed by a hash of everything they depend on, so a rerun skips finished
variants, an interrupted run trains only the variants it had not trained and scores
only the chunks of views it had not scored (``scoring/``, removed once every variant's
scores are written).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import re
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np

from ssga_bench.cache import FeatureCache, stage_key
from ssga_bench.config import Experiment
from ssga_bench.dataset import Dataset
from ssga_bench.dataset_build import build_workspace
from ssga_bench.evaluation import Report
from ssga_bench.execution import Executor, open_executor
from ssga_bench.fusion import fuse_variants
from ssga_bench.heading import with_heading_prior
from ssga_bench.io import atomic_write_bytes, load_npz, npy_bytes, npz_bytes, warn, write_json, write_jsonl
from ssga_bench.ownership import RUN, claim_folder
from ssga_bench.oracle import TrueRender
from ssga_bench.page import write_run_page
from ssga_bench.run_report import write_report
from ssga_bench.scoring import SCORE_CHUNK, ChunkScores, ScoreJob, dataset_identity, score_chunk
from ssga_bench.tasks import chunks
from ssga_bench.timings import Timings
from ssga_bench.training_plan import PSEUDO_VIEWS, TrainingPlan, Views, pseudo_view_records, training_plan
from ssga_bench.variant_training import (
    PSEUDO_CHUNK,
    SCORE_FILES,
    FinishJob,
    FittedVariant,
    Prepared,
    PseudoChunk,
    Trained,
    VariantJob,
    VariantResult,
    finish_variant,
    finished_variant,
    pipeline_options,
    prepare_variant,
    pseudo_graphs,
)
from ssga_bench.workspace import Workspace
from ssga_core.config import ResolvedStage, ResolvedVariant
from ssga_core.errors import SsgaError
from ssga_core.pipeline import Progress, fitting_pseudo_views
from ssga_core.stages import LocalDescriptor


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
        for name, file in SCORE_FILES.items():
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
    executor's workers; then the variants (and oracle rows) train (their pseudo-views'
    graphs in chunks) and score. Results are the same whatever the executor and the
    number of workers.

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
    out = claim_folder(out, RUN)  # replaces only what a run wrote there (ssga_bench.ownership)
    config = experiment.config
    timings = Timings()
    cache = FeatureCache(cache_root if cache_root is not None else out / "cache")
    views = Views(dataset, timings)
    with timings.phase("training plan"), timings.wall_phase("training plan"):
        plan = training_plan(dataset, config.training, views)
        write_jsonl(out / PSEUDO_VIEWS, pseudo_view_records(plan, dataset))
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
    with timings.wall_phase("variants: training graphs, train"):
        trained = _train_variants(todo, plan, root, cache_folder, executor, timings, not_run, progress, variant_progress)
    with timings.wall_phase("variants: score the query views"):
        scored = score_queries([t for _, t in trained], dataset, out, cache, executor, timings, progress)
    for (job, _), result in zip(trained, scored):
        keep(job, result)
    not_run = {rv.label: not_run[rv.label] for rv in experiment.variants if rv.label in not_run}  # in the config's order
    if not results:
        raise SsgaError(f"no variant could run: {'; '.join(not_run.values())}")

    # After the variants' scores are on disk, as they are: a rerun with other prior settings trains nothing.
    results, oracle_results, notes = with_heading_prior(config.prior, dataset, out, results, oracle_results, timings, progress)

    fusion = fuse_variants(experiment, dataset, results, oracle_results, out, timings)
    report = write_report(experiment, dataset, cache, out, results, fusion, not_run, timings, notes)
    write_json(out / "timings.json", timings.to_json())
    write_run_page(out)
    return report, timings


def _train_variants(
    todo: Sequence[VariantJob],
    plan: TrainingPlan,
    root: str,
    cache_folder: str,
    executor: Executor,
    timings: Timings,
    not_run: dict[str, str],
    progress: Progress | None,
    variant_progress: Callable[[str], None] | None,
) -> list[tuple[VariantJob, Trained]]:
    """Train the variants in three maps: their descriptors fitted (a task per variant), the
    pseudo-views' graphs (a task per :data:`PSEUDO_CHUNK` pseudo-views, through every variant), their
    classifiers (a task per variant). A variant without its checkpoint goes into ``not_run``."""

    def bar(phase: str) -> Callable[[int, int], None] | None:
        return (lambda d, n: progress(phase, d, n)) if progress else None

    trained: dict[int, Trained] = {}
    prepared: dict[int, Prepared] = {}
    ran = executor.map(prepare_variant, todo, describe=VariantJob.what, progress=bar("fit the variants' descriptors"))
    for n, (job, outcome) in enumerate(zip(todo, ran)):
        timings.add(outcome.timings)
        if outcome.trained is not None:
            trained[n] = outcome.trained
            if variant_progress:
                variant_progress(f"{job.what()} trained")
        elif outcome.prepared is not None:
            prepared[n] = outcome.prepared
        elif job.oracle is None:
            # A row whose checkpoint is not there is reported as such; the others still run.
            not_run[job.variant.label] = outcome.not_run
            warn(f"{job.variant.label}: not run: {outcome.not_run.removeprefix('no weights: ')}")

    synthesizing = [n for n in prepared if todo[n].variant.variant.synthesizes]
    built = {n: dict(prepared[n].fitting) for n in synthesizing}  # the pseudo-views each descriptor was fitted on
    fitting = set(fitting_pseudo_views(plan.cells, plan.pseudo))
    rest = [i for i in range(len(plan.pseudo)) if i not in fitting] if synthesizing else []
    fitted = tuple(
        FittedVariant(todo[n].variant, todo[n].folder, prepared[n].key, todo[n].oracle, pipeline_options(todo[n].training)) for n in synthesizing
    )
    jobs = [PseudoChunk(root, cache_folder, fitted, tuple((i, plan.pseudo[i]) for i in part)) for part in chunks(rest, PSEUDO_CHUNK)]
    for job, out in zip(jobs, executor.map(pseudo_graphs, jobs, describe=PseudoChunk.what, progress=bar("training graphs"))):
        timings.add(out.timings)
        for n, graphs in zip(synthesizing, out.graphs, strict=True):
            built[n].update(zip((i for i, _ in job.pseudo), graphs, strict=True))

    finish = {n: FinishJob(todo[n], p, [built[n][i] for i in range(len(plan.pseudo))] if n in built else []) for n, p in prepared.items()}
    for n, outcome in zip(finish, executor.map(finish_variant, list(finish.values()), describe=FinishJob.what, progress=bar("train the variants"))):
        timings.add(outcome.timings)
        trained[n] = outcome.trained
        if variant_progress:
            variant_progress(f"{todo[n].what()} trained")
    return [(todo[n], trained[n]) for n in sorted(trained)]


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
    # Before anything starts: a folder holding files a run did not write is refused, unchanged.
    output = claim_folder(output or experiment.config.output, RUN)
    if executor is None:
        with open_executor(experiment.config.execution) as own:
            return run(experiment=experiment, output=output, progress=progress, variant_progress=variant_progress, executor=own)
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
