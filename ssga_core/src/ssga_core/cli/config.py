"""``ssga config``: validate an experiment config, or print its JSON schema."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from ssga_core.cli.main import app, command
from ssga_core.config import experiment_schema, load_experiment

config_app = typer.Typer(help="Validate experiment configs and print their schema.", no_args_is_help=True)
app.add_typer(config_app, name="config")


@command(config_app, name="validate")
def validate_cli(file: Annotated[Path, typer.Argument(help="The experiment config (TOML).")]) -> None:
    """Check a config: its shape, every stage's parameters, every variant and its plugins."""
    experiment = load_experiment(file)
    labels = ", ".join(v.label for v in experiment.variants)
    typer.echo(f"{file}: ok, {len(experiment.variants)} variants: {labels}")


@command(config_app, name="schema")
def schema_cli() -> None:
    """Print the JSON schema of experiment configs, with the installed plugins' parameters."""
    typer.echo(json.dumps(experiment_schema(), indent=2))
