"""``ssga variants``: the valid orders, and the variants a config binds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from ssga_core.cli.main import command, current_registry, read_config
from ssga_core.config import resolve_variants
from ssga_core.kinds import PIPELINE_KIND_NAMES
from ssga_core.variants import order_rows


def config_rows(path: Path) -> list[dict[str, Any]]:
    """One row per variant a config binds: label, order and the plugin of each stage."""
    data, source = read_config(path)
    return [
        {"label": rv.label, "variant": str(rv.variant), **{kind: rv.stages[kind].name if kind in rv.stages else None for kind in PIPELINE_KIND_NAMES}}
        for rv in resolve_variants(source, current_registry(), data)
    ]


def _print_orders(console: Console) -> None:
    table = Table("order", "stages", "paper", "query", "needs", "same as", title="variant orders (any of them may take a preset number: SPD1, SPD2)")
    for row in order_rows():
        needs = "; ".join(f"{kind}: {', '.join(d)}" for kind, d in row["needs"].items()) or "-"
        table.add_row(
            row["order"], " → ".join(row["stages"]), "yes" if row["in_paper"] else "", row["query_path"], needs, ", ".join(row["equivalent_to"]) or "-"
        )
    console.print(table)


def _print_config(console: Console, path: Path, rows: list[dict[str, Any]]) -> None:
    table = Table("label", "variant", *PIPELINE_KIND_NAMES, title=f"variants in {path}")
    for row in rows:
        table.add_row(row["label"], row["variant"], *(row[k] or "-" for k in PIPELINE_KIND_NAMES))
    console.print(table)


@command(name="variants")
def variants_cli(
    list_orders: Annotated[bool, typer.Option("--list", "-l", help="List every valid order (what the command shows without --config).")] = False,
    config: Annotated[Path | None, typer.Option("--config", "-c", metavar="FILE", help="List the variants this experiment config (or a packaged one by name) binds, with their plugins.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")] = False,
) -> None:
    """List the valid variant orders (and which the paper uses), or the variants a config binds, or both."""
    show_orders = list_orders or config is None
    orders = order_rows() if show_orders else None
    bound = config_rows(config) if config is not None else None
    if as_json:
        # One document per request: the orders, the config's variants, or both under their names.
        out: Any = orders if bound is None else bound if orders is None else {"orders": orders, "variants": bound}
        typer.echo(json.dumps(out, indent=2))
        return
    console = Console(width=140)
    if orders is not None:
        _print_orders(console)
    if bound is not None:
        assert config is not None
        _print_config(console, config, bound)
