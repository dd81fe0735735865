"""The benchmark over several seeds: Table 1 per seed, the mean over seeds, and where the time goes.

Each seed draws its own workspace (if the source has a ``seed``), protocol and training;
everything else comes from the experiment config.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path


import numpy as np

from ssga_core.errors import InputError
from ssga_core.plugins import Registry
from ssga_bench.config import Experiment, validate_experiment
from ssga_bench.evaluation import LEVELS, METRICS, Report
from ssga_bench.experiment import Progress, run
from ssga_bench.io import atomic_write_bytes, writable_folder, write_json


@dataclass(frozen=True)
class SeedRun:
    report: Report
    seconds: dict[str, float]
    wall: float


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
    out = writable_folder(output or base.config.output)
    runs: dict[int, SeedRun] = {}
    for seed, experiment in experiments.items():
        if on_seed:
            on_seed(seed)
        start = time.perf_counter()
        folder = out / f"seed-{seed}"
        report, timings = run(experiment=experiment, output=folder, progress=progress, variant_progress=variant_progress)
        runs[seed] = SeedRun(report, dict(timings.seconds), time.perf_counter() - start)
        if on_result:
            on_result(seed, report, folder)
    summary = bench_summary(runs)
    atomic_write_bytes(out / "bench.md", summary.encode())
    write_json(out / "bench.json", {str(s): {"wall_s": r.wall, "seconds": r.seconds, "table": r.report.table} for s, r in runs.items()})
    return summary, runs


def bench_summary(runs: dict[int, SeedRun]) -> str:
    """Markdown: mean (± std) of every row over seeds, the ensemble against each single variant, seconds per phase."""
    seeds = sorted(runs)
    first = runs[seeds[0]].report
    rows = [r for r in first.table if not r.startswith("best single")]
    head = "| | " + " | ".join(f"{m} {lv}" for m in METRICS for lv in LEVELS) + " |"
    lines = [f"## Mean over seeds {', '.join(map(str, seeds))} (± std)", "", head, "|---|" + "---:|" * (len(METRICS) * len(LEVELS))]
    for row in rows:
        cells = []
        for m in METRICS:
            for lv in LEVELS:
                values = np.array([runs[s].report.table[row][lv][m] for s in seeds])
                values = values[~np.isnan(values)]  # a seed whose draw left a level empty
                if not len(values):
                    cells.append("–")
                    continue
                spread = f" ± {values.std(ddof=1):.1f}" if len(values) > 1 else ""
                cells.append(f"{values.mean():.1f}{spread}")
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    ens = first.ensemble
    lines += ["", "## Ensemble vs every single variant (MRR, per seed)", ""]
    for s in seeds:
        t = runs[s].report.table
        for lv in ("L2", "L3"):
            best = max(first.variants, key=lambda v: t[v][lv]["mrr"])
            margin = t[ens][lv]["mrr"] - t[best][lv]["mrr"]
            lines.append(f"- seed {s} {lv}: ensemble {t[ens][lv]['mrr']:.1f} vs best single {best} {t[best][lv]['mrr']:.1f} ({margin:+.1f})")
    phases = sorted({p for s in seeds for p in runs[s].seconds})
    lines += ["", "## Seconds per phase", "", "| phase | " + " | ".join(f"seed {s}" for s in seeds) + " |", "|---|" + "---:|" * len(seeds)]
    for p in phases:
        lines.append(f"| {p} | " + " | ".join(f"{runs[s].seconds.get(p, 0.0):.1f}" for s in seeds) + " |")
    lines.append("| **wall** | " + " | ".join(f"{runs[s].wall:.1f}" for s in seeds) + " |")
    return "\n".join(lines) + "\n"


