"""``ssga run``, ``ssga demo`` and ``ssga bench``: experiments from configs, with progress bars."""

from __future__ import annotations

import time
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Table
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from ssga_core.cli.main import command
from ssga_core.cli.workspace import build_workspace
from ssga_core.config import Experiment, load_experiment, validate_experiment
from ssga_core.evaluation import LEVELS, METRIC_TITLES, METRICS, Report
from ssga_core.io import atomic_write_bytes, write_json

if TYPE_CHECKING:
    from ssga_core.experiment import Timings


def packaged_config(name: str) -> Path:
    """Path of a config shipped with ssga-core (``demo.toml``, ``bench.toml``)."""
    return Path(str(resources.files("ssga_core") / "configs" / name))


def _progress() -> Progress:
    return Progress(TextColumn("{task.description:<32}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn(), transient=True)


def run(experiment: Experiment, *, output: Path | None = None, console: Console | None = None) -> tuple[Report, Timings, dict[str, float]]:
    """Build (or reuse) the experiment's workspace dataset, then train, score and report every variant."""
    # Imported here: torch (through the GCN) takes a second to import, which listing
    # variants or plugins should not pay.
    from ssga_core.experiment import run_experiment

    console = console or Console(stderr=True)
    output = output or experiment.config.output
    ref = experiment.config.workspace
    options = ref.options
    build_seconds: dict[str, float] = {}
    with _progress() as progress:
        start = time.perf_counter()
        dataset = build_workspace(source=ref.name, options=options, protocol=experiment.config.protocol, out=None, progress=progress)
        build_seconds["workspace (plan + render)"] = time.perf_counter() - start
        tasks: dict[str, Any] = {}

        def report(phase: str, done: int, total: int) -> None:
            if phase not in tasks:
                tasks[phase] = progress.add_task(phase, total=total)
            progress.update(tasks[phase], completed=done, total=total)

        def starting(label: str) -> None:
            for task in tasks.values():
                progress.remove_task(task)
            tasks.clear()
            console.print(f"variant {label}")

        result, timings = run_experiment(experiment, dataset, output, progress=report, variant_progress=starting)
    return result, timings, build_seconds


def result_table(report: Report) -> Table:
    """Table 1's layout: a row per variant and reference, Top-1, Top-5 and MRR at L1, L2, L3."""
    table = Table(title=f"{report.title}: test views L1 {report.counts['L1']}, L2 {report.counts['L2']}, L3 {report.counts['L3']}")
    table.add_column("")
    for m in METRICS:
        for lv in LEVELS[:3]:
            table.add_column(f"{METRIC_TITLES[m].split('[')[0]} {lv}", justify="right")
    for label, row in report.table.items():
        style = "bold" if label == report.ensemble else ("dim" if label == "random" else None)
        table.add_row(label, *(f"{row[lv][m]:.1f}" for m in METRICS for lv in LEVELS[:3]), style=style)
    return table


def _print_result(console: Console, report: Report, output: Path) -> None:
    # The table needs ~120 columns; rich assumes 80 when output is not a terminal.
    console.width = max(console.width, 124)
    console.print(result_table(report))
    console.print(f"report: {output / 'report.md'}, {output / 'results.csv'}, {output / 'results.png'}")


@command(name="run")
def run_cli(
    config: Annotated[Path, typer.Argument(help="Experiment config (TOML).")],
    output: Annotated[Path | None, typer.Option(help="Output folder [default: the config's `output`].")] = None,
) -> None:
    """Run an experiment: build its workspace, train and score every variant, fuse, report."""
    experiment = load_experiment(config)
    report, _, _ = run(experiment, output=output)
    _print_result(Console(), report, output or experiment.config.output)


@command(name="demo")
def demo_cli(
    output: Annotated[Path | None, typer.Option(help="Output folder [default: runs/demo].")] = None,
) -> None:
    """The paper's eight variants and their ensemble on a small embedded workspace (a few minutes on a laptop CPU)."""
    start = time.perf_counter()
    experiment = load_experiment(packaged_config("demo.toml"))
    report, _, _ = run(experiment, output=output)
    console = Console()
    _print_result(console, report, output or experiment.config.output)
    console.print(f"demo finished in {time.perf_counter() - start:.0f} s")


@command(name="bench")
def bench_cli(
    config: Annotated[Path | None, typer.Argument(help="Experiment config [default: the packaged bench.toml].")] = None,
    seeds: Annotated[str, typer.Option(help="Comma-separated seeds: one workspace, protocol draw and training seed each.")] = "0,1,2",
    test_per_class: Annotated[int | None, typer.Option(help="Override protocol.test_per_class (smaller for a quick run).")] = None,
    output: Annotated[Path | None, typer.Option(help="Output folder [default: the config's `output`].")] = None,
) -> None:
    """The full protocol on several seeds: Table 1 per seed, the mean over seeds, and where the time goes."""
    base = load_experiment(config or packaged_config("bench.toml"))
    out = output or base.config.output
    console = Console()
    runs: dict[int, dict[str, Any]] = {}
    for seed in (int(s) for s in seeds.split(",") if s.strip()):
        data = base.config.model_dump(mode="json", exclude_none=True)
        if "seed" in base.workspace.cls.Config.model_fields:
            data["workspace"] = {**data["workspace"], "seed": seed}
        data["protocol"] = {**data["protocol"], "seed": seed, **({"test_per_class": test_per_class} if test_per_class else {})}
        data["training"] = {**data["training"], "seed": seed}
        experiment = validate_experiment(data, source=f"{base.source} (seed {seed})")
        console.print(f"[bold]seed {seed}[/bold]")
        start = time.perf_counter()
        report, timings, build = run(experiment, output=out / f"seed-{seed}")
        runs[seed] = {"report": report, "seconds": {**build, **timings.seconds}, "wall": time.perf_counter() - start}
        _print_result(console, report, out / f"seed-{seed}")
    summary = bench_summary(runs)
    atomic_write_bytes(out / "bench.md", summary.encode())
    write_json(out / "bench.json", {str(s): {"wall_s": r["wall"], "seconds": r["seconds"], "table": r["report"].table} for s, r in runs.items()})
    console.print(summary)


def bench_summary(runs: dict[int, dict[str, Any]]) -> str:
    """Markdown: mean (± std) of every row over seeds, and seconds per phase per seed."""
    seeds = sorted(runs)
    first: Report = runs[seeds[0]]["report"]
    rows = [r for r in first.table if not r.startswith("best single")]
    head = "| | " + " | ".join(f"{m} {lv}" for m in METRICS for lv in LEVELS) + " |"
    lines = [f"## Mean over seeds {', '.join(map(str, seeds))} (± std)", "", head, "|---|" + "---:|" * (len(METRICS) * len(LEVELS))]
    for row in rows:
        cells = []
        for m in METRICS:
            for lv in LEVELS:
                values = np.array([runs[s]["report"].table[row][lv][m] for s in seeds])
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
        t = runs[s]["report"].table
        for lv in ("L2", "L3"):
            best = max(first.variants, key=lambda v: t[v][lv]["mrr"])
            margin = t[ens][lv]["mrr"] - t[best][lv]["mrr"]
            lines.append(f"- seed {s} {lv}: ensemble {t[ens][lv]['mrr']:.1f} vs best single {best} {t[best][lv]['mrr']:.1f} ({margin:+.1f})")
    phases = sorted({p for s in seeds for p in runs[s]["seconds"]})
    lines += ["", "## Seconds per phase", "", "| phase | " + " | ".join(f"seed {s}" for s in seeds) + " |", "|---|" + "---:|" * len(seeds)]
    for p in phases:
        lines.append(f"| {p} | " + " | ".join(f"{runs[s]['seconds'].get(p, 0.0):.1f}" for s in seeds) + " |")
    lines.append("| **wall** | " + " | ".join(f"{runs[s]['wall']:.1f}" for s in seeds) + " |")
    return "\n".join(lines) + "\n"

