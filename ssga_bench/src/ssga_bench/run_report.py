"""A run's report and what goes with it: every row evaluated per difficulty level and
heading group (:class:`~ssga_bench.evaluation.Report`), written as ``report.md``,
``results.csv`` and ``results.png``, with the per-query predictions, the drawn queries, the
run page's pictures and the protocol values the build fitted."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ssga_bench.cache import FeatureCache
from ssga_bench.config import Experiment
from ssga_bench.dataset import FITTED, Dataset
from ssga_bench.evaluation import Report
from ssga_bench.figures import birdseye, scene_graph_pictures
from ssga_bench.fusion import Fusion
from ssga_bench.io import atomic_write_bytes, read_jsonl, write_png
from ssga_bench.learned import Learned
from ssga_bench.protocol import Sample
from ssga_bench.queries import draw_queries, save_predictions
from ssga_bench.scoring import dataset_identity
from ssga_bench.timings import Timings
from ssga_bench.training_plan import PSEUDO_VIEWS
from ssga_bench.variant_training import VariantResult
from ssga_core.data import Regions, View
from ssga_core.geometry import Pose


def heading_offset_deg(a: float, b: float) -> float:
    return abs(math.degrees(math.atan2(math.sin(a - b), math.cos(a - b))))


def write_report(
    experiment: Experiment,
    dataset: Dataset,
    cache: FeatureCache,
    out: Path,
    results: Mapping[str, VariantResult],
    fusion: Fusion,
    not_run: Mapping[str, str],
    timings: Timings,
    notes: Sequence[str] = (),
) -> Report:
    """Evaluate the variants' and the fused and reference rows' test scores and write the run's
    report, results, predictions, drawn queries and page pictures into ``out``; ``notes`` go
    under the report's title."""
    config = experiment.config
    labels, ensemble, best_single, references, series = fusion.labels, fusion.ensemble, fusion.best_single, fusion.references, fusion.series
    tests = dataset.split("test")
    truth = np.array([s.place for s in tests])

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
            place_locations=dataset.place_cells,
        )
        report = dataclasses.replace(report, notes=tuple(notes))
    with timings.phase("report"), timings.wall_phase("report"):
        atomic_write_bytes(out / "report.md", report.markdown().encode())
        atomic_write_bytes(out / "results.csv", report.csv().encode())
        atomic_write_bytes(out / "results.png", report.plot())
        # Every row of the report (the variants, the ensemble, the other fusions and references),
        # so `ssga compare` pairs any two of them on the same views.
        rows = {**{label: results[label].test for label in labels}, ensemble[0]: ensemble[1], **references}
        save_predictions(out / "predictions.jsonl", tests, rows, truth, groups={"near": near, "far": ~near}, ensemble=ensemble[0])
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
    return report


def draw_for_the_page(experiment: Experiment, dataset: Dataset, cache: FeatureCache, out: Path, views: int = 3) -> None:
    """The run page's pictures (``page.py``): the workspace map, test cameras by level, and the
    scene graphs of a few test views as the first variant with a parser cut them (its regions
    read back from the feature cache: nothing is parsed again)."""
    pseudo = [Pose(r["pose"]["x"], r["pose"]["y"], r["pose"]["yaw"]) for r in read_jsonl(out / PSEUDO_VIEWS)] if (out / PSEUDO_VIEWS).is_file() else []
    write_png(out / "workspace.png", birdseye(dataset, colour_by="level", pseudo=pseudo))
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
