"""``ssga workspace``: build a benchmark workspace on disk, and look at one."""

from __future__ import annotations

import hashlib
import json
import tomllib
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from ssga_core.cli.main import app, command
from ssga_core.config import load_experiment, resolve_stage
from ssga_core.dataset import Dataset, build_dataset
from ssga_core.errors import InputError
from ssga_core.figures import birdseye, contact_sheet
from ssga_core.io import write_png
from ssga_core.protocol import ProtocolConfig
from ssga_core.stages import WorkspaceSource

workspace_app = typer.Typer(help="Build benchmark workspaces (cells, classes, rendered views) and look at them.", no_args_is_help=True)
app.add_typer(workspace_app, name="workspace")


def parse_option(text: str) -> tuple[str, Any]:
    """``key=value`` with a TOML value (``rooms=5``, ``shading=false``, ``path="a b.glb"``), or a bare string."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise InputError(f"--option {text!r}: expected key=value")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return key.strip(), parsed


def build_workspace(
    *,
    source: str,
    options: dict[str, Any],
    protocol: ProtocolConfig,
    out: Path | None,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> Dataset:
    """Open a workspace source and build its benchmark dataset (see :func:`ssga_core.dataset.build_dataset`)."""
    stage = resolve_stage("workspace", {"name": source, **options})
    workspace_source = stage.create()
    assert isinstance(workspace_source, WorkspaceSource)
    workspace = workspace_source.open()
    source_record = {"name": source, **stage.config.model_dump(mode="json")}
    if out is None:
        # One folder per (source config, protocol): experiments that differ only in their
        # stages share the rendered workspace.
        digest = hashlib.blake2b(json.dumps([source_record, protocol.model_dump(mode="json")], sort_keys=True).encode(), digest_size=4)
        out = Path("runs") / "workspaces" / f"{workspace.name}-{digest.hexdigest()}"
    tasks: dict[str, Any] = {}

    def report(phase: str, done: int, total: int) -> None:
        if progress is None:
            return
        if phase not in tasks:
            tasks[phase] = progress.add_task(f"{workspace.name}: {phase}", total=total)
        progress.update(tasks[phase], completed=done, total=total)

    height = float(getattr(stage.config, "camera_height", 1.5))
    return build_dataset(
        workspace,
        out,
        source=source_record,
        protocol=protocol,
        height=height,
        overwrite=overwrite,
        progress=report,
    )


@command(workspace_app, name="build")
def build_cli(
    config: Annotated[Path | None, typer.Option("--config", "-c", help="Take [workspace] and [protocol] from this experiment config.")] = None,
    source: Annotated[str, typer.Option(help="Workspace source plugin (`ssga plugins` lists them).")] = "procedural",
    option: Annotated[list[str] | None, typer.Option("--option", "-o", help="A parameter of the source, key=value; repeatable.")] = None,
    seed: Annotated[int | None, typer.Option(help="Seed of the protocol, and of the source if it has one.")] = None,
    cells: Annotated[int | None, typer.Option(help="Location cells (classes = cells x 12).")] = None,
    test_per_class: Annotated[int | None, typer.Option(help="Test views per class (the paper: 1500).")] = None,
    cell_size: Annotated[float | None, typer.Option(help="Side of a location cell, metres.")] = None,
    out: Annotated[Path | None, typer.Option(help="Dataset folder [default: runs/workspaces/<workspace>-<settings hash>].")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace a dataset built with other settings.")] = False,
) -> None:
    """Plan and render a benchmark workspace; an interrupted build resumes where it stopped."""
    options = dict(parse_option(o) for o in option or [])
    protocol = ProtocolConfig()
    if config is not None:
        experiment = load_experiment(config)
        ref = experiment.config.workspace
        source, options = ref.name, {**ref.options, **options}
        protocol = experiment.config.protocol
    overrides = {k: v for k, v in {"seed": seed, "cells": cells, "test_per_class": test_per_class, "cell_size": cell_size}.items() if v is not None}
    protocol = ProtocolConfig.model_validate({**protocol.model_dump(), **overrides})
    if seed is not None:
        options.setdefault("seed", seed)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, transient=False) as progress:
        dataset = build_workspace(source=source, options=options, protocol=protocol, out=out, overwrite=overwrite, progress=progress)
    levels = dataset.plan.level_counts()
    typer.echo(
        f"{dataset.root}: {dataset.num_classes} classes, {len(dataset.split('train'))} real training views, "
        f"{len(dataset.split('test'))} test views (L1 {levels[1]}, L2 {levels[2]}, L3 {levels[3]})"
    )


@command(workspace_app, name="show")
def show_cli(
    dataset: Annotated[Path, typer.Argument(help="A dataset folder made by `ssga workspace build`.")],
    colour_by: Annotated[str, typer.Option("--by", help="Colour test cameras by 'class' or 'level'.")] = "class",
    out: Annotated[Path | None, typer.Option(help="Folder for the pictures [default: the dataset folder].")] = None,
) -> None:
    """Draw a bird's-eye plan (walls, cells, cameras and frusta) and a contact sheet of views."""
    if colour_by not in ("class", "level"):
        raise InputError(f"--by {colour_by!r}: expected 'class' or 'level'")
    data = Dataset.open(dataset)
    out = out or dataset
    plan_png, sheet_png = out / f"birdseye-by-{colour_by}.png", out / "contact-sheet.png"
    write_png(plan_png, birdseye(data, colour_by=colour_by))
    write_png(sheet_png, contact_sheet(data))
    typer.echo(f"{plan_png}\n{sheet_png}")
