"""``ssga compare``: two rows of a run or bench, paired on the same test views."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ssga_core.cli import command


def compare_cli(
    output: Annotated[Path, typer.Argument(metavar="OUTPUT", help="The output folder of `ssga run` or `ssga bench`.")],
    a: Annotated[str, typer.Argument(metavar="A", help="The row subtracted, as the report labels it, e.g. 'SIFT-SL (PSD)' or 'Ensemble (RRF) of all'; 'ensemble': the ensemble row, whatever members each seed chose; 'nearest neighbour': the nearest-neighbour reference, whichever variant's features.")],
    b: Annotated[str, typer.Argument(metavar="B", help="The row it is subtracted from, e.g. 'SIFT-SE (PSD)'.")],
    out: Annotated[Path | None, typer.Option(metavar="FILE.md", help="Also write the tables to this file.")] = None,
    b_from: Annotated[
        Path | None,
        typer.Option(
            "--b-from",
            metavar="OUTPUT",
            help="Take row B from this other output folder (the same seeds and test views): two configs compared view by view.",
        ),
    ] = None,
) -> None:
    """Row B minus row A per difficulty level, paired view by view (per seed, and the mean over seeds): did a swapped stage help?"""
    from ssga_bench.compare import compare
    from ssga_bench.io import atomic_write_bytes

    text = compare(output, a, b, b_output=b_from)
    if out is not None:
        atomic_write_bytes(out, text.encode())
    typer.echo(text, nl=False)


def register(app: typer.Typer) -> None:
    command(app, name="compare")(compare_cli)
