"""``ssga variants``: the valid orders, or the variants a config binds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from ssga_core.cli.main import command
from ssga_core.config import load_experiment
from ssga_core.variants import STAGE_VERBS, all_orders, equivalents, parse_variant, requirements


def order_rows() -> list[dict[str, Any]]:
    """One row per valid order: its stages, whether the paper uses it, its needs, its equivalents."""
    rows = []
    for order in all_orders():
        variant = parse_variant(order)
        needs = {kind: sorted(str(d) for d in data) for kind, data in requirements(order).items() if data}
        rows.append(
            {
                "order": order,
                "stages": [STAGE_VERBS[s] for s in order],
                "in_paper": variant.in_paper,
                "query_path": variant.query_order,
                "synthesizes": variant.synthesizes,
                "needs": needs,
                "equivalent_to": equivalents(order),
            }
        )
    return rows


def config_rows(path: Path) -> list[dict[str, Any]]:
    """One row per variant a config binds: label, order and the plugin of each stage."""
    experiment = load_experiment(path)
    return [
        {
            "label": rv.label,
            "variant": str(rv.variant),
            **{kind: rv.stages[kind].cls.name if kind in rv.stages else None for kind in ("parser", "descriptor", "synthesizer")},
        }
        for rv in experiment.variants
    ]


@command(name="variants")
def variants_cli(
    list_orders: Annotated[bool, typer.Option("--list", "-l", help="List every valid order (the default).")] = False,
    config: Annotated[Path | None, typer.Option("--config", "-c", help="Show the variants this config binds instead.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """List the valid variant orders (and which the paper uses), or the variants a config binds."""
    del list_orders  # listing is what the command does without --config
    if config is not None:
        rows = config_rows(config)
        if as_json:
            typer.echo(json.dumps(rows, indent=2))
            return
        table = Table("label", "variant", "parser", "descriptor", "synthesizer", title=f"variants in {config}")
        for row in rows:
            table.add_row(row["label"], row["variant"], *(row[k] or "-" for k in ("parser", "descriptor", "synthesizer")))
        Console(width=120).print(table)
        return
    rows = order_rows()
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
        return
    table = Table("order", "stages", "paper", "query", "needs", "same as", title="variant orders (any of them may take a preset number: SPD1, SPD2)")
    for row in rows:
        needs = "; ".join(f"{kind}: {', '.join(d)}" for kind, d in row["needs"].items()) or "-"
        table.add_row(
            row["order"],
            " → ".join(row["stages"]),
            "yes" if row["in_paper"] else "",
            row["query_path"],
            needs,
            ", ".join(row["equivalent_to"]) or "-",
        )
    Console(width=140).print(table)
