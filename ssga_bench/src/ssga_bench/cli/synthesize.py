"""``ssga synthesize``: what a synthesizer makes of one image seen from a moved camera."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ssga_core.cli import command, current_registry
from ssga_core.config import resolve_stage
from ssga_bench.cli import MaxSideOption, parse_option
from ssga_bench.io import WORKING_SIDE


def synthesize_cli(
    image: Annotated[Path, typer.Argument(metavar="IMAGE", help="The source image (PNG, JPEG or any format OpenCV reads).")],
    synthesizer: Annotated[str, typer.Option(metavar="NAME", help="Synthesizer plugin (`ssga plugins` lists them).")],
    move: Annotated[str, typer.Option(metavar="FORWARD,LEFT,YAW_DEG", help="The target camera: metres ahead, metres to the left, degrees turned left.")],
    out: Annotated[Path, typer.Option(metavar="DIR", help="Folder for synthetic.png, depth.png, holes.png and side-by-side.png.")],
    depth: Annotated[Path | None, typer.Option(metavar="FILE", help="The image's metric depth (a 16-bit PNG of millimetres, or a NumPy file of metres), for synthesizers that need it.")] = None,
    hfov: Annotated[float, typer.Option(min=1.0, max=179.0, metavar="DEGREES", help="Horizontal field of view of the camera.")] = 90.0,
    option: Annotated[list[str] | None, typer.Option("--option", "-o", metavar="KEY=VALUE", help="A parameter of the synthesizer (or preset=NAME); repeatable.")] = None,
    max_side: MaxSideOption = WORKING_SIDE,
) -> None:
    """Render IMAGE from a moved camera with any synthesizer, with its depth, its holes and a side-by-side picture (the paper's Fig. 3)."""
    from ssga_bench.synthesize import parse_move, synthesize_image

    target = parse_move(move)
    ref = {"name": synthesizer, **dict(parse_option(o) for o in option or [])}
    stage = resolve_stage("synthesizer", ref, current_registry(), source="command-line options").create()
    resized_from = synthesize_image(stage, image, target, out, depth=depth, hfov_deg=hfov, max_side=max_side or None)
    caveat = type(stage).caveat(stage.config)
    reduced = f" (its {resized_from[0]} x {resized_from[1]} read reduced to --max-side {max_side})" if resized_from else ""
    typer.echo(f"{out / 'side-by-side.png'}: {image}{reduced} from {target[0]:g} m ahead, {target[1]:g} m left, turned {target[2]:g} degrees" + (f" [{caveat}]" if caveat else ""))


def register(app: typer.Typer) -> None:
    command(app, name="synthesize")(synthesize_cli)
