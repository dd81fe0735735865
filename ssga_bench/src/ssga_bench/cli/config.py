"""``ssga config``: validate experiment configs, or print their JSON schema."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Annotated

import typer

from ssga_core.cli import command, current_registry
from ssga_core.errors import SsgaError
from ssga_bench.config import experiment_schema, load_experiment, packaged_config, packaged_presets

config_app = typer.Typer(help="Validate experiment configs and print their schema.", no_args_is_help=True, rich_markup_mode=None)


def validate_cli(files: Annotated[list[Path], typer.Argument(metavar="CONFIG...", help="Experiment configs (TOML).")]) -> None:
    """Check configs: shape, every stage's parameters, every variant and its plugins. Exits 1 if any has a problem."""
    registry = current_registry()
    failed = 0
    for file in files:
        try:
            experiment = load_experiment(file, registry)
        except SsgaError as exc:
            typer.echo(f"error: {exc}", err=True)
            failed += 1
            continue
        labels = ", ".join(v.label for v in experiment.variants)
        typer.echo(f"{file}: ok, {len(experiment.variants)} variants: {labels}")
    if failed:
        raise typer.Exit(1)


def schema_cli() -> None:
    """Print the JSON schema of experiment configs, with the installed plugins' parameters."""
    typer.echo(json.dumps(experiment_schema(current_registry()), indent=2))


def presets_cli() -> None:
    """List the packaged experiments: `ssga run NAME`, or `preset = "NAME"` in a config of your own."""
    for name in packaged_presets():
        lines = packaged_config(f"{name}.toml").read_text(encoding="utf-8").splitlines()
        comment = " ".join(line.lstrip("#").strip() for line in itertools.takewhile(lambda line: line.startswith("#"), lines))
        typer.echo(f"{name:<8} {comment.split('. ')[0].rstrip('.')}")


def register(app: typer.Typer) -> None:
    command(config_app, name="validate")(validate_cli)
    command(config_app, name="schema")(schema_cli)
    command(config_app, name="presets")(presets_cli)
    app.add_typer(config_app, name="config")
