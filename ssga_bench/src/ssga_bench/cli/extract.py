"""``ssga extract``: any installed descriptor's local features for a set of images, as hloc's HDF5."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ssga_core.cli import command, current_registry
from ssga_core.config import resolve_stage
from ssga_bench.cli import AddressOption, ExecutorOption, WorkersOption, execution_options, parse_option, progress_bars


def extract_cli(
    images: Annotated[list[Path], typer.Argument(metavar="IMAGES...", help="Images to describe (PNG, JPEG or any format OpenCV reads); other sizes than 256 x 256 are resized.")],
    descriptor: Annotated[str, typer.Option(metavar="NAME", help="Descriptor plugin (`ssga plugins` lists them).")],
    out: Annotated[Path, typer.Option(metavar="FILE.h5", help="HDF5 file to write (hloc's layout), whole or not at all.")],
    option: Annotated[list[str] | None, typer.Option("--option", "-o", metavar="KEY=VALUE", help="A parameter of the descriptor (or preset=NAME); repeatable.")] = None,
    executor: ExecutorOption = None,
    workers: WorkersOption = None,
    address: AddressOption = None,
) -> None:
    """Write each image's features in hloc's layout: per image, keypoints (N x 2, x then y) and descriptors (D x N)."""
    from ssga_bench.execution import open_executor
    from ssga_bench.extract import SIZE, extract_features

    ref = {"name": descriptor, **dict(parse_option(o) for o in option or [])}
    stage = resolve_stage("descriptor", ref, current_registry(), source="command-line options")
    execution = execution_options(None, executor, workers, address)
    with progress_bars() as bars, open_executor(execution) as runner:
        resized = extract_features(images, stage, out, progress=bars, executor=runner, batch=execution.batch)
    caveat = stage.cls.caveat(stage.config)
    for name, (w, h) in resized.items():
        typer.echo(f"{name}: resized from {w} x {h} to {SIZE} x {SIZE}", err=True)
    typer.echo(f"{out}: {len(images)} images, descriptor {descriptor!r}" + (f" [{caveat}]" if caveat else ""))


def register(app: typer.Typer) -> None:
    command(app, name="extract")(extract_cli)
