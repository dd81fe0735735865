"""Two rows, paired on the same test views: did swapping a stage (or a config) help?

Each row of a report (a variant, the ensemble, a reference) ranks the same test views.
Row B minus row A, view by view, is a paired difference: its t-interval is far
narrower than the two rows' own intervals, because what makes one view hard makes it
hard for both. Per seed of a bench run, and the mean of the seeds' differences with a
t-interval across seeds (what a rerun on other homes would see).

Reads ``predictions.jsonl`` (written by ``ssga run``), or ``seed-*/predictions.jsonl``
(``ssga bench``). Row B may come from another output folder of the same seeds and test
views (``b_output``): two configs compared view by view, e.g. the GCN against graph
matching. ``ensemble`` names the ensemble row of each seed, whatever members it chose, and
``nearest neighbour`` the nearest-neighbour reference, whichever variant's features it uses.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ssga_bench.evaluation import FUSED, LEVELS, METRIC_TITLES, METRICS, NEAREST, Estimate, difference_text, mean_interval, per_query, seeds_estimate
from ssga_bench.queries import load_predictions
from ssga_core import InputError


def prediction_files(output: Path) -> dict[str, Path]:
    """``{"seed 0": path, ...}`` of a bench output folder, or ``{"run": path}`` of a run's; none is an error."""
    if (output / "predictions.jsonl").is_file():
        return {"run": output / "predictions.jsonl"}
    seeds = sorted(output.glob("seed-*/predictions.jsonl"), key=lambda p: int(p.parent.name.split("-", 1)[1]))
    if not seeds:
        raise InputError(f"{output}: no predictions.jsonl, nor seed-*/predictions.jsonl; expected the output folder of `ssga run` or `ssga bench`")
    return {p.parent.name.replace("-", " "): p for p in seeds}


ENSEMBLE = "ensemble"
"""The name that stands for a run's ensemble row, whose label may name the members each seed chose."""


def row_label(records: list[dict[str, Any]], name: str, where: str) -> str:
    """The label of row ``name`` in ``records``: the name itself, or the row :data:`ENSEMBLE` or :data:`NEAREST` stands for."""
    entries = records[0]["rows"] if records else {}
    if name in entries:
        return name
    if name == ENSEMBLE:
        marked = [label for label, entry in entries.items() if entry.get("ensemble")]
        # Predictions written before the mark hold one ``Ensemble (...)`` row, the ensemble's.
        found = marked or [label for label in entries if label.startswith(FUSED + " (")]
    elif name == NEAREST:
        found = [label for label in entries if label.startswith(NEAREST + " (")]
    else:
        found = []
    if len(found) == 1:
        return found[0]
    raise InputError(
        f"{where}: no row {name!r}; the rows are: {', '.join(map(repr, entries))}, "
        f"or {ENSEMBLE!r} for the ensemble's, {NEAREST!r} for the nearest neighbour's"
    )


def paired_differences(
    records: list[dict[str, Any]], a: str, b: str, metric: str, where: str, records_b: list[dict[str, Any]] | None = None, where_b: str = ""
) -> dict[str, Estimate]:
    """Per level group, ``metric(b) - metric(a)`` over the views both rows ranked, with its paired
    interval; row ``b`` from ``records_b`` (another run of the same test views) if given."""
    records_b, where_b = (records, where) if records_b is None else (records_b, where_b)
    a, b = row_label(records, a, where), row_label(records_b, b, where_b)
    if [r["id"] for r in records] != [r["id"] for r in records_b]:
        raise InputError(f"{where_b}: other test views than {where}; compare outputs of the same seeds and protocol")
    diff = per_query(np.array([r["rows"][b]["rank"] for r in records_b]), metric) - per_query(np.array([r["rows"][a]["rank"] for r in records]), metric)
    level = np.array([r["level"] for r in records])
    return {g: mean_interval(diff if g == "all" else diff[level == int(g[1])]) for g in LEVELS}


def compare(output: Path, a: str, b: str, metrics: tuple[str, ...] = METRICS, b_output: Path | None = None) -> str:
    """Markdown: for each metric, row ``b`` (of ``b_output`` if given) minus row ``a`` per seed and level, and the mean over seeds."""
    files = prediction_files(output)
    files_b = prediction_files(b_output) if b_output is not None else files
    if set(files_b) != set(files):
        raise InputError(f"{b_output}: holds {', '.join(files_b)}, {output} holds {', '.join(files)}; compare outputs of the same seeds")
    per_seed = {name: load_predictions(path) for name, path in files.items()}
    per_seed_b = {name: load_predictions(path) for name, path in files_b.items()} if b_output is not None else per_seed
    head = f"{b} of {b_output} − {a} of {output}" if b_output is not None else f"{b} − {a}"
    lines = [f"# {head}", "", f"Paired on the same test views of {output}; percentage points, ± half the 95% interval.", ""]
    for metric in metrics:
        lines += [f"## {METRIC_TITLES[metric]}", "", "| | " + " | ".join(LEVELS) + " |", "|---|" + "---:|" * len(LEVELS)]
        by_seed = {
            name: paired_differences(records, a, b, metric, str(files[name]), per_seed_b[name], str(files_b[name]))
            for name, records in per_seed.items()
        }
        for name, diffs in by_seed.items():
            lines.append(f"| {name} | " + " | ".join(f"{difference_text(diffs[g])} (n {diffs[g].n})" for g in LEVELS) + " |")
        if len(by_seed) > 1:
            means = {g: seeds_estimate([d[g] for d in by_seed.values()]) for g in LEVELS}
            lines.append(f"| mean of {len(by_seed)} seeds | " + " | ".join(difference_text(means[g]) for g in LEVELS) + " |")
        lines.append("")
    lines.append("better / worse: the interval excludes zero; tie: it does not.")
    return "\n".join(lines) + "\n"
