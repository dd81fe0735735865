"""The benchmark over several seeds: Table 1 per seed, the mean over seeds, and where the time goes.

Each seed draws its own workspace (if the source has a ``seed``), protocol and training;
everything else comes from the experiment config.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path


import numpy as np

from ssga_core.errors import InputError
from ssga_core.variants import VariantSyntaxError, parse_variant
from ssga_core.plugins import Registry
from ssga_bench.config import Experiment, validate_experiment
from ssga_bench.evaluation import HALVINGS, LOCATION, LOCATION_NOTE, METRIC_TITLES, METRICS, THIN, Estimate, Report, difference_text, seeds_estimate
from ssga_bench.execution import open_executor
from ssga_bench.experiment import Progress, run
from ssga_bench.io import atomic_write_bytes, write_json
from ssga_bench.ownership import BENCH, RUN, check_folder, claim_folder
from ssga_bench.page import write_bench_page


@dataclass(frozen=True)
class SeedRun:
    """One seed's run: its report, the work per stage and phase (summed over workers), its wall time and wall phases."""

    report: Report
    seconds: dict[str, float]
    wall: float
    phases: dict[str, float] = field(default_factory=dict)
    views: dict[str, int] = field(default_factory=dict)
    """Views each per-view stage handled (for its rate)."""
    workers: int = 1
    """Workers of the executor it ran on."""


def parse_seeds(text: str) -> list[int]:
    """``"0,1,2"`` -> ``[0, 1, 2]``; anything else is a one-line error naming the text."""
    parts = [p.strip() for p in text.split(",")]
    if not text.strip() or not all(p.isascii() and p.isdecimal() for p in parts):
        raise InputError(f"--seeds {text!r}: expected comma-separated non-negative integers, e.g. 0,1,2")
    seeds = [int(p) for p in parts]
    if len(set(seeds)) != len(seeds):
        raise InputError(f"--seeds {text!r}: a seed is repeated")
    return seeds


def seed_experiment(base: Experiment, seed: int, registry: Registry, test_per_class: int | None = None) -> Experiment:
    """``base`` with the workspace (if its source has a seed), protocol and training drawn with ``seed``."""
    data = base.config.model_dump(mode="json", exclude_none=True)
    data["workspace"] = {"name": base.workspace.name, **base.workspace.config.model_dump(mode="json")}
    if "seed" in base.workspace.cls.Config.model_fields:
        data["workspace"]["seed"] = seed
    data["fuser"] = {"name": base.fuser.name, **base.fuser.config.model_dump(mode="json")}
    data["protocol"] = {**data["protocol"], "seed": seed, **({"test_per_class": test_per_class} if test_per_class is not None else {})}
    data["training"] = {**data["training"], "seed": seed}
    return validate_experiment(data, registry, source=f"{base.source} (seed {seed})", base_dir=base.base_dir)


def run_bench(
    *,
    base: Experiment,
    seeds: Sequence[int],
    registry: Registry,
    output: Path | None = None,
    test_per_class: int | None = None,
    on_seed: Callable[[int], None] | None = None,
    on_result: Callable[[int, Report, Path], None] | None = None,
    progress: Progress | None = None,
    variant_progress: Callable[[str], None] | None = None,
) -> tuple[str, dict[int, SeedRun]]:
    """Run ``base`` once per seed into ``output/seed-<n>``; write and return the summary (``bench.md``, ``bench.json``)."""
    if not seeds:
        raise InputError("no seed to run")
    # Every seed's experiment is validated before any runs: a seed or test_per_class out of
    # range is an error now, not after the seeds before it have run for hours.
    experiments = {seed: seed_experiment(base, seed, registry, test_per_class) for seed in seeds}
    # Replaces only what a bench (and each seed's run) wrote there, said before anything is written (ssga_bench.ownership).
    root = Path(output or base.config.output)
    for seed in seeds:
        check_folder(root / f"seed-{seed}", RUN)
    out = claim_folder(root, BENCH)
    runs: dict[int, SeedRun] = {}
    # One executor for every seed: workers start once and keep what they opened.
    with open_executor(base.config.execution) as executor:
        for seed, experiment in experiments.items():
            if on_seed:
                on_seed(seed)
            start = time.perf_counter()
            folder = out / f"seed-{seed}"
            report, timings = run(experiment=experiment, output=folder, progress=progress, variant_progress=variant_progress, executor=executor)
            wall = time.perf_counter() - start
            runs[seed] = SeedRun(report, dict(timings.seconds), wall, dict(timings.wall), dict(timings.views), executor.workers)
            if on_result:
                on_result(seed, report, folder)
    summary = bench_summary(runs)
    atomic_write_bytes(out / "bench.md", summary.encode())
    write_json(
        out / "bench.json",
        {str(s): {"wall_s": r.wall, "phases": r.phases, "seconds": r.seconds, "views": r.views, "table": r.report.table} for s, r in runs.items()},
    )
    write_bench_page(out, summary, sorted(runs))
    return summary, runs


TRAIN_SHARE_TARGET = 15.0
"""Percent of wall time the GCN training phase should stay under."""


def _seed_table(runs: dict[int, SeedRun], metrics: Sequence[str] = METRICS) -> list[str]:
    seeds = sorted(runs)
    groups = runs[seeds[0]].report.levels
    # Rows by their key across seeds (the best single variant's label changes with the seed).
    keyed = [{row.key: row for row in runs[s].report.rows.values()} for s in seeds]
    kinds = {key: row.kind for rows in keyed for key, row in rows.items()}
    head = "| | " + " | ".join(f"{METRIC_TITLES[m]} {g}" for m in metrics for g in groups) + " |"
    lines = [head, "|---|" + "---:|" * (len(metrics) * len(groups))]
    for key, kind in kinds.items():
        per_seed = [rows[key].stats for rows in keyed if key in rows]
        cells = [seeds_estimate([stats[g][m] for stats in per_seed if g in stats]).text() for m in metrics for g in groups]
        name = f"**{key}**" if kind == "ensemble" else key
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    for label in dict.fromkeys(label for s in seeds for label in runs[s].report.not_run):
        if label not in kinds:
            lines.append(f"| {label} ⚠ | " + " | ".join("not run" for _ in metrics for _ in groups) + " |")
    return lines


def _ensemble_lines(runs: dict[int, SeedRun], groups: Sequence[str] = ("L2", "L3")) -> list[str]:
    seeds = sorted(runs)
    variants = list(dict.fromkeys(v for s in seeds for v in runs[s].report.variants))
    head = "| ensemble − variant | " + " | ".join(f"seed {s} {g}" for s in seeds for g in groups) + " |"
    lines = [head, "|---|" + "---:|" * (len(seeds) * len(groups))]
    wins: dict[str, list[bool]] = {g: [] for g in groups}
    for v in variants:
        cells = []
        for s in seeds:
            report = runs[s].report
            for g in groups:
                if v not in report.variants:
                    cells.append("–")
                    continue
                d = report.compare(v, g)
                cells.append(difference_text(d))
                if not np.isnan(d.value):
                    wins[g].append(d.value > 0)
        lines.append(f"| {v} | " + " | ".join(cells) + " |")
    lines.append("")
    for g, won in wins.items():
        lines.append(f"- {g}: the ensemble's MRR is higher in {sum(won)} of {len(won)} (variant, seed) pairs")
    return lines


def part_twins(labels: Sequence[str]) -> list[tuple[str, str]]:
    """Each part-based variant among ``labels`` with its twin: the same order without P, on the same descriptor
    (``SIFT-SL (PDS)`` and ``SIFT (DS)``, as :func:`ssga_core.pipeline.table_label` names them), where both are there.
    A preset number pairs with the twin of the same number, else with the plain order (``P-SL (SPD1)`` with ``P
    (SD)``): a preset's numbered variants usually differ in S's settings, which its twin without P need not repeat."""
    twins = []
    for label in labels:
        head, _, rest = label.rpartition(" (")
        try:
            variant = parse_variant(rest.removesuffix(")"))
        except VariantSyntaxError:  # not a variant's table label (the stand-in rows of a test, a plugin's own name)
            continue
        if "P" not in variant.order or "-" not in head:
            continue
        without_parts = replace(variant, order=variant.order.replace("P", ""))
        for candidate in dict.fromkeys((without_parts, replace(without_parts, preset=None))):
            twin = f"{head.rpartition('-')[0]} ({candidate})"
            if twin in labels:
                twins.append((label, twin))
                break
    return twins


def _claims_lines(runs: dict[int, SeedRun], groups: Sequence[str] = ("L1", "L2", "L3")) -> list[str]:
    """Per seed and level: the ensemble against the nearest neighbour and against every single variant, and each
    part-based variant against its twin without P; with more than one seed, each difference's mean over the seeds per
    level; then how many cells hold each claim."""
    seeds = sorted(runs)
    pairs = list(dict.fromkeys(p for s in seeds for p in part_twins(runs[s].report.variants)))
    columns = ["seed", "level", "ensemble − nearest neighbour", "ensemble − its best variant there", *(f"{a} − {b}" for a, b in pairs)]
    lines = ["| " + " | ".join(columns) + " |", "|---|---|" + "---:|" * (len(columns) - 2)]
    lead = above = not_below = above_other_half = cells = 0
    near_wins = near_cells = 0
    parts_up = dict.fromkeys(pairs, 0)
    parts_cells = dict.fromkeys(pairs, 0)
    # level -> column title -> each seed's difference, for the rows of means
    per_level: dict[str, dict[str, list[Estimate]]] = {g: {} for g in groups}
    for s in seeds:
        report = runs[s].report
        nearest = report.nearest_neighbour
        for g in groups:
            if not report.counts.get(g) or not report.variants:
                continue
            cells += 1
            row = [str(s), g]
            seen = per_level[g]
            beats_nearest = True  # a run without a nearest-neighbour row is judged on the single variants alone
            if nearest is not None:
                d = report.difference(report.ensemble, nearest, g)
                lead += d.value >= NEAREST_LEAD
                beats_nearest = d.value > 0
                row.append(difference_text(d))
                seen.setdefault(columns[2], []).append(d)
            else:
                row.append("–")
            behind = {v: report.compare(v, g) for v in report.variants}
            best = min(behind, key=lambda v: behind[v].value)
            above += behind[best].value >= 0
            if g in NEAR_LEVELS:
                near_cells += 1
                near_wins += behind[best].value >= 0 and beats_nearest
            not_below += all(d.value + d.half_width >= 0 for d in behind.values())
            above_other_half += report.against_chosen_on_other_half(g) >= 0
            row.append(f"{difference_text(behind[best])} ({best})")
            seen.setdefault(columns[3], []).append(behind[best])
            for column, (a, b) in zip(columns[4:], pairs):
                if a not in report.variants or b not in report.variants:
                    row.append("–")
                    continue
                d = report.difference(a, b, g)
                if g in PART_LEVELS:
                    parts_cells[a, b] += 1
                    parts_up[a, b] += d.value > 0
                row.append(difference_text(d))
                seen.setdefault(column, []).append(d)
            lines.append("| " + " | ".join(row) + " |")
    if len(seeds) > 1:
        # How large each claim is on the whole, with the spread a rerun on other seeds would see (as the table of means).
        for g, seen in per_level.items():
            if seen:
                row = ["mean", g]
                row += [difference_text(seeds_estimate(seen[c])) if c in seen else "–" for c in columns[2:]]
                lines.append("| " + " | ".join(row) + " |")
    lines += [
        "",
        f"- the ensemble {NEAREST_LEAD:g} points or more above the nearest neighbour: {lead} of {cells} (seed, level) cells"
        + ("" if any(runs[s].report.nearest_neighbour for s in seeds) else " (no nearest-neighbour row)"),
        f"- the ensemble at or above every single variant: {above} of {cells} ({not_below} not below one beyond its interval; "
        f"{above_other_half} at or above the one chosen best on the other half of the cell's views, {HALVINGS} random halvings)",
        f"- the ensemble at or above every single variant and above the nearest neighbour at {' and '.join(NEAR_LEVELS)}: "
        f"{near_wins} of {near_cells}",
        f"- each part-based variant above its twin without P at {' and '.join(PART_LEVELS)}: "
        + ("; ".join(f"{a} − {b} {parts_up[a, b]} of {parts_cells[a, b]}" for a, b in pairs) or "no twins"),
    ]
    return lines


def _fused_rows_lines(runs: dict[int, SeedRun], groups: Sequence[str] = ("L1", "L2", "L3")) -> list[str]:
    """Every fused row (the ensemble, then the rules reported beside it) against the bar the goals set, over the (seed,
    level) cells: its MRR less the higher of the best single variant's and the nearest neighbour's + NEAREST_LEAD.
    The presets chose their ensemble row by the mean of this margin (docs/experiments.md)."""
    margins: dict[str, list[float]] = {}
    above: dict[str, int] = {}
    ensemble_keys = set()
    for s in sorted(runs):
        report = runs[s].report
        nearest, table = report.nearest_neighbour, report.table
        ensemble_keys.add(report.rows[report.ensemble].key)
        for g in groups:
            if not report.counts.get(g) or not report.variants:
                continue
            mrr = {label: by_group[g]["mrr"] for label, by_group in table.items()}
            best = max(mrr[v] for v in report.variants)
            bar = goals_bar(best, mrr[nearest] if nearest is not None else None)
            for label in report.fused:
                key = report.rows[label].key
                margins.setdefault(key, []).append(mrr[label] - bar)
                above[key] = above.get(key, 0) + (mrr[label] >= best)
    lines = ["| fused row | cells | at or above every single variant | mean margin over the bar |", "|---|---:|---:|---:|"]
    for key, values in margins.items():
        name = f"**{key}** (the ensemble row)" if key in ensemble_keys else key
        lines.append(f"| {name} | {len(values)} | {above[key]} | {np.mean(values):+.2f} |")
    return lines


def goals_bar(best_single: float, nearest: float | None) -> float:
    """The MRR a fused row must reach in a (seed, level) cell to meet both of the project's goals there: every single
    variant's (``best_single``, the highest of them) and the nearest neighbour's + :data:`NEAREST_LEAD` (None: no
    nearest-neighbour row)."""
    return best_single if nearest is None else max(best_single, nearest + NEAREST_LEAD)


NEAREST_LEAD = 2.0
"""MRR points by which the ensemble should lead the nearest neighbour over the same features: the project's goal for the
method, so that the classifier, the parts and the fusion are seen to add to the features themselves."""
PART_LEVELS = ("L2", "L3")
"""Where a part-based variant should beat its twin without P: the harder levels, where the paper says parsing helps most."""
NEAR_LEVELS = ("L1", "L2")
"""Where the demo's ensemble should beat every single variant and the nearest neighbour: the levels with most of its test
views, where a first run's table is read."""


def _ceiling_lines(runs: dict[int, SeedRun], groups: Sequence[str] = ("L1", "L2", "L3")) -> list[str]:
    """Per seed: the ensemble, the best variant of each level and the best variant for each view."""
    lines = [f"{' / '.join(groups)}, as a seed has them:", ""]
    lines += ["| seed | ensemble | the best variant of each level | the best variant for each view |", "|---|---:|---:|---:|"]
    for s in sorted(runs):
        report = runs[s].report
        if not report.variants:
            continue
        present = [g for g in groups if report.counts.get(g)]
        ensemble = " / ".join(f"{report.table[report.ensemble][g]['mrr']:.1f}" for g in present)
        of_level = " / ".join(f"{report.table[report.best_variant_of_level(g)][g]['mrr']:.1f}" for g in present)
        per_view = " / ".join(f"{report.best_variant_per_view(g):.1f}" for g in present)
        lines.append(f"| {s} | {ensemble} | {of_level} | {per_view} |")
    return lines


def _phase_lines(runs: dict[int, SeedRun]) -> list[str]:
    seeds = sorted(runs)
    lines = ["Wall time of each phase of the run (the workers' work overlaps within a phase):", ""]
    lines += ["| phase | " + " | ".join(f"seed {s} [s]" for s in seeds) + " | share of wall [%] (mean) |", "|---|" + "---:|" * (len(seeds) + 1)]
    for phase in dict.fromkeys(p for s in seeds for p in runs[s].phases):
        seconds = " | ".join(f"{runs[s].phases.get(phase, 0.0):.1f}" for s in seeds)
        share = np.mean([100 * runs[s].phases.get(phase, 0.0) / runs[s].wall if runs[s].wall > 0 else float("nan") for s in seeds])
        lines.append(f"| {phase} | {seconds} | {share:.1f} |")
    lines.append("| **wall** | " + " | ".join(f"{runs[s].wall:.1f}" for s in seeds) + " | 100 |")
    lines += ["", "Work of each stage, summed over every worker that did it:", ""]
    lines += ["| stage | " + " | ".join(f"seed {s} [s]" for s in seeds) + " |", "|---|" + "---:|" * len(seeds)]
    for stage in sorted({p for s in seeds for p in runs[s].seconds}):
        lines.append(f"| {stage} | " + " | ".join(f"{runs[s].seconds.get(stage, 0.0):.1f}" for s in seeds) + " |")
    train = float(np.mean([100 * runs[s].seconds.get("train", 0.0) / max(sum(runs[s].seconds.values()), 1e-9) for s in seeds]))
    verdict_ = "within" if train <= TRAIN_SHARE_TARGET else "over"
    lines += ["", f"GCN training (`train`) takes {train:.1f}% of the work: {verdict_} the target of ≤ {TRAIN_SHARE_TARGET:.0f}%."]
    lines += ["", *_throughput_lines(runs)]
    return lines


def _throughput_lines(runs: dict[int, SeedRun]) -> list[str]:
    """Test views per second end to end, each per-view stage's own rate on one worker, and the
    end-to-end rate over the slowest stage's rate on every worker of the run."""
    seeds = sorted(runs)
    lines = ["| throughput | " + " | ".join(f"seed {s}" for s in seeds) + " |", "|---|" + "---:|" * len(seeds)]
    lines.append("| end to end [test views/s] | " + " | ".join(f"{end_to_end_rate(runs[s]):.2f}" for s in seeds) + " |")
    rates = {s: stage_rates(runs[s]) for s in seeds}
    for stage in dict.fromkeys(st for s in seeds for st in rates[s]):
        lines.append(f"| {stage}, one worker [views/s] | " + " | ".join(f"{rates[s][stage]:.1f}" if stage in rates[s] else "–" for s in seeds) + " |")
    lines.append("| workers | " + " | ".join(str(runs[s].workers) for s in seeds) + " |")
    lines.append(
        "| end to end / slowest stage on every worker [%] | "
        + " | ".join(f"{100 * end_to_end_rate(runs[s]) / (min(rates[s].values()) * runs[s].workers):.0f}" if rates[s] else "–" for s in seeds)
        + " |"
    )
    return lines


def end_to_end_rate(run: SeedRun) -> float:
    """Test views per second of wall time, from the workspace to the report."""
    return sum(run.report.counts.get(level, 0) for level in ("L1", "L2", "L3")) / run.wall


def stage_rates(run: SeedRun) -> dict[str, float]:
    """Views per second of each per-view stage on one worker (views it handled / its seconds of work)."""
    return {stage: n / run.seconds[stage] for stage, n in run.views.items() if n and run.seconds.get(stage, 0.0) > 0}


def bench_summary(runs: dict[int, SeedRun]) -> str:
    """Markdown: every row's mean over seeds with a 95% interval, test views per level, the ensemble
    against each single variant per seed at L2 and L3, and seconds per phase with their share of wall time."""
    seeds = sorted(runs)
    reports = {s: runs[s].report for s in seeds}
    groups = list(dict.fromkeys(g for r in reports.values() for g in r.counts))
    interval = "95% t-interval across seeds" if len(seeds) > 1 else "one seed: 95% per-query intervals"
    lines = [f"## Mean over seeds {', '.join(map(str, seeds))} (± {interval})", ""]
    lines += [f"_Seed {s}: {note}_\n" for s, r in reports.items() for note in r.notes]  # e.g. a heading prior every row carries
    lines += [*_seed_table(runs), ""]
    if all(r.has_location for r in reports.values()):
        lines += ["## Top-1 of the location (the first class at the right cell, whatever its heading)", "", LOCATION_NOTE, ""]
        lines += [*_seed_table(runs, (LOCATION,)), ""]
    lines += ["## Test views per group", "", "| seed | " + " | ".join(groups) + " |", "|---|" + "---:|" * len(groups)]
    lines += [f"| {s} | " + " | ".join(str(r.counts.get(g, 0)) for g in groups) + " |" for s, r in reports.items()]
    thin = sorted({f"{g} (seed {s}: n={n})" for s, r in reports.items() for g, n in r.thin_groups().items()})
    if thin:
        lines += ["", f"Too thin to read (n < {THIN}): " + ", ".join(thin)]
    not_run = sorted({f"{label} (seed {s}): {why}" for s, r in reports.items() for label, why in r.not_run.items()})
    if not_run:
        lines += ["", "Not run:", *(f"- {line}" for line in not_run)]
    lines += ["", "## Ensemble vs every single variant (MRR, percentage points, paired 95% interval per seed)", ""]
    lines += _ensemble_lines(runs)
    lines += ["", "## The method's claims, seed by seed (MRR, percentage points, paired 95% interval)", ""]
    lines += [
        "Does fusing the variants beat each of them, and the nearest neighbour over the same features? Does parsing beat the "
        "same order without it? Each cell is one seed's test views of one level; a row \"mean\" averages the seeds' differences, "
        "its interval across the seeds (the spread a rerun on other seeds would see).",
        "",
        *_claims_lines(runs),
        "",
        f"Each fused row against the bar the goals set: per (seed, level) cell, its MRR less the higher of the best single "
        f"variant's and the nearest neighbour's + {NEAREST_LEAD:g} (MRR points; at or above zero in every cell meets both goals).",
        "",
        *_fused_rows_lines(runs),
    ]
    lines += ["", "## What choosing among the variants could reach (MRR, read on the test labels: ceilings, not results)", ""]
    lines += _ceiling_lines(runs)
    lines += ["", "## Where the time goes", "", *_phase_lines(runs)]
    return "\n".join(lines) + "\n"
