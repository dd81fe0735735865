"""``ssga plugins``: what is installed, from which distribution, with which config."""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from ssga_core.cli.main import command, current_registry
from ssga_core.plugins import plugin_rows


def _fields(schema: dict[str, Any]) -> str:
    props = schema.get("properties", {})
    return ", ".join(f"{k}={v['default']!r}" if "default" in v else k for k, v in props.items()) or "-"


@command(name="plugins")
def plugins_cli(as_json: Annotated[bool, typer.Option("--json", help="Print JSON, with each config's full schema.")] = False) -> None:
    """List installed stage plugins: distribution, version, kind, name and config."""
    registry = current_registry()
    rows = plugin_rows(registry)
    if as_json:
        failures = [{"plugin": f.plugin.name, "distribution": f.plugin.distribution, "reason": f.reason} for f in registry.failures]
        typer.echo(json.dumps({"plugins": rows, "failures": failures}, indent=2))
        return
    table = Table("distribution", "version", "kind", "name", "consumes → produces", "config (defaults)", title="ssga plugins")
    for row in rows:
        flow = f"{', '.join(row['consumes']) or '-'} → {', '.join(row['produces']) or '-'}"
        table.add_row(row["distribution"] or row["entry_point"], row["version"], row["kind"], row["name"], flow, _fields(row["config_schema"]))
    Console(width=160).print(table)
    learned = [row for row in rows if row["layouts"]]
    if learned:
        layouts = Table("kind", "name", "layout", "where the files come from", title="checkpoint layouts: weights = FILE alone says which")
        for row in learned:
            for layout in row["layouts"]:
                layouts.add_row(row["kind"], row["name"], layout["name"], layout["source"])
        Console(width=160).print(layouts)
