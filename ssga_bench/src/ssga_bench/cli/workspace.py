"""``ssga workspace``: build a benchmark workspace on disk, and look at one."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from pydantic import ValidationError

from ssga_core.cli import command, current_registry
from ssga_core.config import ResolvedStage, pydantic_problems, resolve_stage
from ssga_core.errors import ConfigError, InputError
from ssga_bench.cli import AddressOption, ExecutorOption, WorkersOption, execution_options, parse_option, progress_bars

if TYPE_CHECKING:
    from ssga_bench.protocol import ProtocolConfig

workspace_app = typer.Typer(
    help="Build benchmark workspaces (cells, classes, rendered views) and look at them.", no_args_is_help=True, rich_markup_mode=None
)


def build_cli(
    config: Annotated[
        Path | None, typer.Option("--config", "-c", metavar="FILE", help="Take the workspace and protocol from this experiment config [default: the demo's].")
    ] = None,
    source: Annotated[str | None, typer.Option(metavar="NAME", help="Workspace source plugin (`ssga plugins` lists them) [default: the config's].")] = None,
    option: Annotated[list[str] | None, typer.Option("--option", "-o", metavar="KEY=VALUE", help="A parameter of the source, key=value; repeatable.")] = None,
    seed: Annotated[int | None, typer.Option(min=0, metavar="N", help="Seed of the protocol, and of the source if it has one.")] = None,
    cells: Annotated[int | None, typer.Option(metavar="N", help="Location cells (classes = cells x 12).")] = None,
    test_per_class: Annotated[int | None, typer.Option(metavar="N", help="Test views per class (the paper: 1500).")] = None,
    cell_size: Annotated[float | None, typer.Option(metavar="METRES", help="Side of a location cell, metres.")] = None,
    viewpoint_distance: Annotated[
        float | None, typer.Option(metavar="METRES", help="Farthest a canonical viewpoint stands behind its cell's centroid, metres.")
    ] = None,
    test_radius: Annotated[float | None, typer.Option(metavar="METRES", help="Test views stand within this distance of their cell's centroid, metres.")] = None,
    suggest: Annotated[
        bool,
        typer.Option(
            "--suggest",
            help="Build nothing: say how many cells each cell size and viewpoint distance gives on this workspace, and which "
            "test radius places the test views.",
        ),
    ] = False,
    out: Annotated[Path | None, typer.Option(metavar="DIR", help="Dataset folder [default: runs/workspaces/<workspace>-<settings hash>].")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace a dataset built with other settings (only the files ssga wrote).")] = False,
    decode: Annotated[
        bool,
        typer.Option("--decode", help="Over an existing dataset: check every view file's data too (a bit flipped inside), not only its size, header and end, and re-make what is damaged."),
    ] = False,
    executor: ExecutorOption = None,
    workers: WorkersOption = None,
    address: AddressOption = None,
) -> None:
    """Plan and render a benchmark workspace; an interrupted build resumes where it stopped, and over a finished one
    whatever is missing or damaged is re-made (the same, bit for bit). With --suggest, only say
    which cell size, viewpoint distance and test radius give the wanted cells on it."""
    from ssga_bench.config import load_experiment, packaged_config
    from ssga_bench.dataset_build import build_workspace
    from ssga_bench.execution import open_executor
    from ssga_bench.protocol import ProtocolConfig

    registry = current_registry()
    base = load_experiment(config or packaged_config("demo.toml"), registry)
    given = dict(parse_option(o) for o in option or [])
    options: dict[str, Any] = {}
    if source is None:
        # The base's source, already resolved: its paths follow its config file; new options follow the current folder.
        source = base.workspace.name
        options = base.workspace.config.model_dump()
    if seed is not None and "seed" in registry.get("workspace", source).Config.model_fields:
        options["seed"] = seed
    given_values = {
        "seed": seed,
        "cells": cells,
        "test_per_class": test_per_class,
        "cell_size": cell_size,
        "viewpoint_distance": viewpoint_distance,
        "test_radius": test_radius,
    }
    overrides = {k: v for k, v in given_values.items() if v is not None}
    try:
        protocol = ProtocolConfig.model_validate({**base.config.protocol.model_dump(), **overrides})
    except ValidationError as exc:
        raise ConfigError("command-line options", pydantic_problems(exc, ("protocol",))) from None
    stage = resolve_stage("workspace", {"name": source, **options, **given}, registry, source="command-line options")
    if suggest:
        typer.echo("\n".join(suggest_protocol(stage=stage, protocol=protocol)))
        return
    execution = execution_options(base.config.execution, executor, workers, address)
    with progress_bars(transient=False) as bars, open_executor(execution) as runner:
        dataset = build_workspace(stage, protocol, out=out, overwrite=overwrite, progress=bars, executor=runner, batch=execution.batch, decode=decode)
    levels = dataset.plan.level_counts()
    n = len(dataset.remade)
    remade = f"; re-made {n} damaged or missing file{'s' if n != 1 else ''}" if n else ""
    typer.echo(
        f"{dataset.root}: {dataset.num_classes} classes, {len(dataset.split('train'))} real training views, "
        f"{len(dataset.split('test'))} test views (L1 {levels[1]}, L2 {levels[2]}, L3 {levels[3]}){remade}"
    )


def suggest_protocol(*, stage: ResolvedStage, protocol: ProtocolConfig) -> list[str]:
    """What ``ssga workspace build --suggest`` prints: the cells each cell size and viewpoint
    distance gives on the workspace (with the configured ones first), and the test radius."""
    from ssga_bench.protocol import capture_height, suggest, suggestion_kinds
    from ssga_bench.workspace import Workspace

    workspace = stage.create().open()
    rendered = isinstance(workspace, Workspace)
    suggestion = suggest(
        workspace.floor_plan,
        workspace.camera,
        protocol,
        height=workspace.camera_height if rendered else capture_height(workspace.captures),
        captures=None if rendered else workspace.captures,
        limit=protocol.cells,
        check_test_radius=True,
    )
    one_change = [f for f in suggestion.fits if len(f.changes(protocol)) <= 1]
    shown = one_change if any(f.enough for f in one_change[1:]) else list(suggestion.fits)
    lines = [
        f"workspace {workspace.name!r}: {workspace.floor_plan.free.area:.1f} m^2 of free floor; {protocol.cells} cells wanted, "
        f"each seen from all {protocol.orientations} headings" + ("" if rendered else " and holding captures"),
        f"  {'cell_size':>9}  {'viewpoint_distance':>18}  cells (of the grid's)",
    ]
    for fit in shown:
        count = f"{fit.cells}{'' if fit.complete else '+'} of {fit.grid_cells}"
        note = "  <- configured" if not fit.changes(protocol) else ("" if fit.enough else "  too few")
        lines.append(f"  {fit.cell_size:>9g}  {fit.viewpoint_distance:>18g}  {count}{note}")
    best = suggestion.best
    if best is None:
        lines.append(f"no value tried gives {protocol.cells} cells: lower protocol.cells (at most {max(f.cells for f in suggestion.fits)})")
        return lines
    if not best.changes(protocol):
        lines.append(f"the configured values give {protocol.cells} cells")
    else:
        lines.append("to get them: " + "; or ".join(f.describe(protocol) for f in suggestion_kinds(shown, protocol)[:3]))
    if suggestion.test_radius_checked:
        views = "test views" + (f" (with {best.describe(protocol)})" if best.changes(protocol) else "")
        if suggestion.test_radius is None:
            lines.append(f"{views}: none of the test radii tried places them all; lower protocol.test_per_class")
        elif suggestion.test_radius == protocol.test_radius:
            lines.append(f"{views}: all placed within protocol.test_radius = {protocol.test_radius:g}")
        else:
            lines.append(f"{views}: protocol.test_radius = {suggestion.test_radius:g} places them all ({protocol.test_radius:g} does not)")
    return lines


def show_cli(
    dataset: Annotated[Path, typer.Argument(metavar="DATASET", help="A dataset folder made by `ssga workspace build`.")],
    colour_by: Annotated[str, typer.Option("--by", metavar="class|level", help="Colour test cameras by 'class' or 'level'.")] = "class",
    out: Annotated[Path | None, typer.Option(metavar="DIR", help="Folder for the pictures [default: the dataset folder].")] = None,
) -> None:
    """Draw a bird's-eye plan (walls, cells, cameras and frusta) and a contact sheet of views."""
    from ssga_bench.dataset import Dataset
    from ssga_bench.figures import draw_workspace

    paths = draw_workspace(dataset=Dataset.open(dataset), colour_by=colour_by, out=out)
    typer.echo("\n".join(map(str, paths)))


def verify_cli(
    dataset: Annotated[Path, typer.Argument(metavar="DATASET", help="A dataset folder made by `ssga workspace build`.")],
    decode: Annotated[
        bool, typer.Option("--decode", help="Check every view file's chunk CRCs and image data too, not only its size, header and end (slower).")
    ] = False,
) -> None:
    """Check a dataset's files without changing them: each damaged or missing one on a line, exit 1 if any
    (`ssga workspace build` over the folder, with the config it was built from, re-makes them)."""
    from ssga_bench.health import check_dataset

    health = check_dataset(dataset, decode=decode)
    for line in health.lines():
        typer.echo(line)
    if not health.healthy:
        raise InputError(health.summary())
    typer.echo(health.summary())


def register(app: typer.Typer) -> None:
    command(workspace_app, name="build")(build_cli)
    command(workspace_app, name="show")(show_cli)
    command(workspace_app, name="verify")(verify_cli)
    app.add_typer(workspace_app, name="workspace")
