"""``ssga parse``: what any installed parser makes of a set of images, drawn as scene graphs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ssga_core.cli import command, current_registry
from ssga_core.config import resolve_stage
from ssga_core.errors import InputError
from ssga_bench.cli import AddressOption, ExecutorOption, MaxSideOption, WorkersOption, execution_options, parse_option, progress_bars
from ssga_bench.io import WORKING_SIDE


def parse_cli(
    images: Annotated[list[Path], typer.Argument(metavar="IMAGES...", help="Images to parse (PNG, JPEG or any format OpenCV reads).")],
    parser: Annotated[str, typer.Option(metavar="NAME", help="Parser plugin (`ssga plugins` lists them).")],
    out: Annotated[Path, typer.Option(metavar="DIR", help="Folder for NAME.graph.png, NAME.labels.png and NAME.regions.json per image.")],
    option: Annotated[list[str] | None, typer.Option("--option", "-o", metavar="KEY=VALUE", help="A parameter of the parser (device=cpu for a learned one); repeatable.")] = None,
    preset: Annotated[str | None, typer.Option(metavar="P", help="One of the parser's presets to start from; options override it.")] = None,
    rgb_only: Annotated[bool, typer.Option("--rgb-only", help="Ignore the depth and id files ssga wrote beside an image (a workspace's or a synthesis's).")] = False,
    max_side: MaxSideOption = WORKING_SIDE,
    executor: ExecutorOption = None,
    workers: WorkersOption = None,
    address: AddressOption = None,
) -> None:
    """Draw each image's scene graph (regions, boxes, edges, class names, the whole-image node) and write its regions."""
    from ssga_bench.execution import open_executor
    from ssga_bench.parse import parse_images

    options = dict(parse_option(o) for o in option or [])
    if preset is not None and options.setdefault("preset", preset) != preset:
        raise InputError(f"--preset {preset!r} and -o preset={options['preset']!r}: expected one preset")
    stage = resolve_stage("parser", {"name": parser, **options}, current_registry(), source="command-line options")
    execution = execution_options(None, executor, workers, address)
    with progress_bars() as bars, open_executor(execution) as runner:
        parsed = parse_images(
            images, stage, out, preset=options.get("preset"), companions=not rgb_only, progress=bars, executor=runner, batch=execution.batch,
            max_side=max_side or None,
        )
    caveat = stage.cls.caveat(stage.config)
    for p in parsed:
        extra = f" (read with {', '.join(p.channels[1:])})" if len(p.channels) > 1 else ""
        if p.resized_from:
            extra += f" (its {p.resized_from[0]} x {p.resized_from[1]} read reduced to --max-side {max_side})"
        typer.echo(f"{p.picture}: {p.image}: {p.regions} regions, {p.edges} edges between them{extra}" + (f" [{caveat}]" if caveat else ""))


def register(app: typer.Typer) -> None:
    command(app, name="parse")(parse_cli)
