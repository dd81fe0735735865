"""``ssga run``, ``ssga demo`` and ``ssga bench``: experiments from configs, with progress bars."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from ssga_core.cli import command, current_registry
from ssga_bench.cli import AddressOption, ExecutorOption, WorkersOption, execution_options, progress_bars
from ssga_bench.config import Experiment, load_experiment, packaged_config
from ssga_bench.evaluation import LEVELS, METRIC_TITLES, METRICS, Report


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
    console.print(f"report: {output / 'index.html'} (the run on one page), {output / 'report.md'}, {output / 'results.csv'}, {output / 'results.png'}")


def with_execution(experiment: Experiment, executor: str | None, workers: int | None, address: str | None) -> Experiment:
    """``experiment`` with the command line's execution options over its ``[execution]``."""
    execution = execution_options(experiment.config.execution, executor, workers, address)
    return dataclasses.replace(experiment, config=experiment.config.model_copy(update={"execution": execution}))


def _run(experiment: Experiment, output: Path | None) -> None:
    from ssga_bench.experiment import run  # torch, through the GCN: only for the commands that train

    with progress_bars() as bars:
        report, _ = run(experiment=experiment, output=output, progress=bars, variant_progress=bars.variant)
    _print_result(Console(), report, output or experiment.config.output)


def run_cli(
    config: Annotated[Path, typer.Argument(metavar="CONFIG", help="Experiment config (TOML), or a packaged one by name: demo, bench, paper.")],
    output: Annotated[Path | None, typer.Option(metavar="DIR", help="Output folder [default: the config's `output`].")] = None,
    executor: ExecutorOption = None,
    workers: WorkersOption = None,
    address: AddressOption = None,
) -> None:
    """Run an experiment: build its workspace, train and score every variant, fuse, report."""
    _run(with_execution(load_experiment(config, current_registry()), executor, workers, address), output)


def demo_cli(
    output: Annotated[Path | None, typer.Option(metavar="DIR", help="Output folder [default: runs/demo].")] = None,
    executor: ExecutorOption = None,
    workers: WorkersOption = None,
    address: AddressOption = None,
) -> None:
    """The paper's eight variants, a layout member and their ensemble on a small embedded workspace (about three minutes on a 2-core laptop)."""
    start = time.perf_counter()
    _run(with_execution(load_experiment(packaged_config("demo.toml"), current_registry()), executor, workers, address), output)
    Console().print(f"demo finished in {time.perf_counter() - start:.0f} s")


def bench_cli(
    config: Annotated[Path | None, typer.Argument(metavar="CONFIG", show_default=False, help="Experiment config, or a packaged one by name (demo, bench, paper) [default: bench].")] = None,
    seeds: Annotated[str, typer.Option(metavar="N,N,...", help="Comma-separated seeds: one workspace, protocol draw and training seed each.")] = "0,1,2",
    test_per_class: Annotated[
        int | None, typer.Option(min=1, metavar="N", help="Override protocol.test_per_class (smaller for a quick run).")
    ] = None,
    output: Annotated[Path | None, typer.Option(metavar="DIR", help="Output folder [default: the config's `output`].")] = None,
    executor: ExecutorOption = None,
    workers: WorkersOption = None,
    address: AddressOption = None,
) -> None:
    """The full protocol on several seeds: Table 1 per seed, the mean over seeds, and where the time goes."""
    from ssga_bench.bench import parse_seeds, run_bench

    registry = current_registry()
    seed_list = parse_seeds(seeds)
    base = with_execution(load_experiment(config or packaged_config("bench.toml"), registry), executor, workers, address)
    console = Console()
    with progress_bars() as bars:
        summary, _ = run_bench(
            base=base,
            seeds=seed_list,
            registry=registry,
            output=output,
            test_per_class=test_per_class,
            on_seed=lambda seed: console.print(f"[bold]seed {seed}[/bold]"),
            on_result=lambda seed, report, folder: _print_result(console, report, folder),
            progress=bars,
            variant_progress=bars.variant,
        )
    console.print(summary)
    folder = output or base.config.output
    console.print(f"bench: {folder / 'index.html'} (every seed on one page), {folder / 'bench.md'}")


def register(app: typer.Typer) -> None:
    command(app, name="run")(run_cli)
    command(app, name="demo")(demo_cli)
    command(app, name="bench")(bench_cli)
