#!/usr/bin/env python
"""Did one change to a preset pass the rule it was tried under? Two ``ssga bench`` outputs of the same seeds.

The presets' changes are decided by a rule written down before the runs are read (docs/experiments.md, e.g.
"Whitened where S drew"): the preset as committed (BEFORE) and the same seeds with the one change (AFTER,
usually a hard-linked copy of BEFORE rescored with an overlay config), read on tuning homes only. The rule
this script reads, over the (seed, level) cells of L1, L2 and L3:

(a) the ensemble's mean MRR rises by ``--gain`` or more;
(b) its mean margin over the goals' bar (its MRR less the higher of the best single variant's and the
    nearest neighbour's + 2, as ``bench.md`` computes it) rises by ``--gain`` or more;
(c) no part twin (PDS − DS, PSD − SD, ... as ``bench.md`` pairs them) is above zero at L2 and L3 in fewer
    cells than before.

With ``--keep-margin FLOOR``, (b) reads instead: the mean margin stays at or above FLOOR, and neither goal
(2 points above the nearest neighbour; at or above every single variant) holds in fewer cells than before;
for a change that lifts the members with their fusion, which the margin's rise cannot show.

With ``--beyond-interval``, the counts of (b) and (c) hold a cell lost only where the shortfall is beyond its
paired 95% interval (read from each seed's ``predictions.jsonl``, as ``bench.md``'s "not below one beyond its
interval"): the ensemble not below the nearest neighbour + 2, nor below any single variant, nor a part-based
variant below its twin, beyond the interval of the difference on the cell's test views. On two tuning homes a
cell's tie (intervals of ±3 to ±5 points at L2 and L3) falls either side of zero by chance; so counted, a
change is judged on the cells it moves beyond their noise.

It prints each cell before and after, how many cells meet each goal, each member's mean change, and the
verdict; on held-out homes read it as a report, not a choice.

    .venv/bin/python scripts/preset_rule.py runs/s29-p146 runs/s29-p146-t1
"""

from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ssga_bench.bench import NEAREST_LEAD, PART_LEVELS, goals_bar, part_twins
from ssga_bench.compare import ENSEMBLE, paired_differences
from ssga_bench.evaluation import NEAREST
from ssga_bench.queries import load_predictions

from ssga_core import InputError, SsgaError

LEVELS = ("L1", "L2", "L3")


@dataclass(frozen=True)
class Cell:
    """One (seed, level) of a bench output: each row's MRR and what the goals read from them."""

    ensemble: float
    nearest: float | None
    variants: dict[str, float]

    @property
    def best(self) -> tuple[str, float]:
        label = max(self.variants, key=self.variants.__getitem__)
        return label, self.variants[label]

    @property
    def margin(self) -> float:
        return self.ensemble - goals_bar(self.best[1], self.nearest)


def read_cells(output: Path, seed: int) -> dict[str, Cell]:
    """Each level's :class:`Cell` of ``output/seed-<seed>/results.csv``."""
    path = output / f"seed-{seed}" / "results.csv"
    if not path.is_file():
        raise InputError(f"{path}: no such file; expected the output folder of `ssga bench` with seed {seed}")
    mrr: dict[str, dict[str, float]] = {}
    kinds: dict[str, str] = {}
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            if row["group"] in LEVELS and row["mrr"]:
                kinds[row["row"]] = row["kind"]
                mrr.setdefault(row["row"], {})[row["group"]] = float(row["mrr"])
    ensemble = [label for label, kind in kinds.items() if kind == "ensemble"]
    nearest = [label for label in kinds if label.startswith(NEAREST + " (")]
    if len(ensemble) != 1:
        raise InputError(f"{path}: expected one ensemble row, found {len(ensemble)}")
    variants = [label for label, kind in kinds.items() if kind == "variant"]
    return {
        g: Cell(mrr[ensemble[0]][g], mrr[nearest[0]][g] if nearest else None, {v: mrr[v][g] for v in variants if g in mrr[v]})
        for g in LEVELS
        if g in mrr[ensemble[0]]
    }


def summary(cells: dict[tuple[int, str], Cell]) -> dict[str, float | int]:
    """The rule's figures over ``cells``: mean MRR and margin, the goals' counts, each part twin's count."""
    values = list(cells.values())
    out = {
        "mean MRR": float(np.mean([c.ensemble for c in values])),
        "mean margin": float(np.mean([c.margin for c in values])),
        "cells": len(values),
        "nearest neighbour + 2": sum(c.nearest is None or c.ensemble >= c.nearest + NEAREST_LEAD for c in values),
        "at or above every single variant": sum(c.ensemble >= c.best[1] for c in values),
    }
    for (_seed, level), c in cells.items():
        for part, twin in part_twins(list(c.variants)):
            key = f"{part} − {twin} > 0 at {' and '.join(PART_LEVELS)}"
            out.setdefault(key, 0)
            out[key] += level in PART_LEVELS and c.variants[part] - c.variants[twin] > 0
    return out


BEYOND = ", not short beyond its interval"
"""The tail of a count that ``--beyond-interval`` reads instead of the plain one."""


def interval_summary(output: Path, cells: dict[tuple[int, str], Cell]) -> dict[str, int]:
    """The goals' and the part twins' counts over ``cells`` (of ``output``), each cell held unless its shortfall is
    beyond the paired 95% interval of the difference on its test views (``seed-*/predictions.jsonl``)."""
    out: dict[str, int] = {}
    records: dict[int, list] = {}
    differences: dict[tuple[int, str, str], dict] = {}  # every level's at once, so each pair is read once a seed
    for (seed, level), cell in cells.items():
        path = output / f"seed-{seed}" / "predictions.jsonl"
        if seed not in records:
            if not path.is_file():
                raise InputError(f"{path}: no such file; --beyond-interval reads each seed's predictions.jsonl")
            records[seed] = load_predictions(path)

        def high(a: str, b: str) -> float:  # the top of the 95% interval of b − a at this level
            if (seed, a, b) not in differences:
                differences[seed, a, b] = paired_differences(records[seed], a, b, "mrr", str(path))
            return differences[seed, a, b][level].high

        held = {
            "nearest neighbour + 2": cell.nearest is None or high(NEAREST, ENSEMBLE) >= NEAREST_LEAD,
            "at or above every single variant": all(high(v, ENSEMBLE) >= 0 for v in cell.variants),
        }
        for part, twin in part_twins(list(cell.variants)):
            if level in PART_LEVELS:
                held[f"{part} − {twin} > 0 at {' and '.join(PART_LEVELS)}"] = high(twin, part) >= 0
        for name, ok in held.items():
            out[name + BEYOND] = out.get(name + BEYOND, 0) + bool(ok)
    return out


GOALS = ("nearest neighbour + 2", "at or above every single variant")


def margin_failures(before: dict[str, float], after: dict[str, float], gain: float, keep_margin: float | None, tail: str = "") -> list[str]:
    """What fails part (b) of the rule: the margin's rise, or with ``keep_margin`` its floor and the goals' counts
    (``tail``: :data:`BEYOND` for the counts read against their intervals)."""
    if keep_margin is None:
        return ["(b) mean margin"] if after["mean margin"] - before["mean margin"] < gain else []
    failed = [f"(b) mean margin below {keep_margin:+g}"] if after["mean margin"] < keep_margin else []
    return failed + [f"(b) {goal + tail}" for goal in GOALS if after[goal + tail] < before[goal + tail]]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path, help="the preset as committed (an `ssga bench` output folder)")
    parser.add_argument("after", type=Path, help="the same seeds with the change")
    parser.add_argument("--seeds", help="comma-separated seeds (default: every seed both folders have)")
    parser.add_argument("--gain", type=float, default=0.5, help="what (a) and (b) ask, MRR points [0.5]")
    parser.add_argument("--keep-margin", type=float, metavar="FLOOR", help="(b): the mean margin at or above FLOOR and no goal's count down")
    parser.add_argument(
        "--beyond-interval", action="store_true", help="(b)'s and (c)'s counts: a cell lost only where it falls short beyond its paired 95%% interval"
    )
    args = parser.parse_args(argv)
    try:
        if args.seeds:
            seeds = [int(s) for s in args.seeds.split(",")]
        else:
            found = [{int(p.name.split("-", 1)[1]) for p in folder.glob("seed-*") if (p / "results.csv").is_file()} for folder in (args.before, args.after)]
            seeds = sorted(found[0] & found[1])
        if not seeds:
            raise InputError(f"{args.before}, {args.after}: no seed has a results.csv in both")
        runs = {}
        for name, folder in (("before", args.before), ("after", args.after)):
            runs[name] = {(s, g): c for s in seeds for g, c in read_cells(folder, s).items()}
        if runs["before"].keys() != runs["after"].keys():
            raise InputError(f"{args.before}, {args.after}: the two runs do not have the same (seed, level) cells")
        before, after = summary(runs["before"]), summary(runs["after"])
        if args.beyond_interval:
            before.update(interval_summary(args.before, runs["before"]))
            after.update(interval_summary(args.after, runs["after"]))
    except (SsgaError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1

    print(f"seeds {', '.join(map(str, seeds))}; MRR in %, before -> after\n")
    print("| seed | level | ensemble | best single variant | nearest neighbour | margin over the goals' bar |")
    print("|---|---|---|---|---|---|")
    for key, b in runs["before"].items():
        a = runs["after"][key]
        nearest = "–" if b.nearest is None or a.nearest is None else f"{b.nearest:.1f} -> {a.nearest:.1f}"
        print(
            f"| {key[0]} | {key[1]} | {b.ensemble:.1f} -> {a.ensemble:.1f} | {b.best[1]:.1f} ({b.best[0]}) -> {a.best[1]:.1f} ({a.best[0]}) "
            f"| {nearest} | {b.margin:+.2f} -> {a.margin:+.2f} |"
        )
    print("\n| over the cells | before | after |\n|---|---:|---:|")
    for name in dict.fromkeys([*before, *after]):
        fmt = "{:.2f}" if isinstance(before.get(name, 0), float) else "{}"
        print(f"| {name} | {fmt.format(before.get(name, '–'))} | {fmt.format(after.get(name, '–'))} |")
    print("\n| member | mean change |\n|---|---:|")
    for label in runs["before"][next(iter(runs["before"]))].variants:
        changes = [runs["after"][k].variants[label] - c.variants[label] for k, c in runs["before"].items() if label in runs["after"][k].variants]
        if changes:
            print(f"| {label} | {np.mean(changes):+.2f} |")

    tail = BEYOND if args.beyond_interval else ""
    twins = [name for name in before if " − " in name and name.endswith(BEYOND) == args.beyond_interval]
    failed = [
        *(["(a) mean MRR"] if after["mean MRR"] - before["mean MRR"] < args.gain else []),
        *(margin_failures(before, after, args.gain, args.keep_margin, tail)),
        *(f"(c) {name}" for name in twins if after.get(name, 0) < before[name]),
    ]
    gains = f"mean MRR {after['mean MRR'] - before['mean MRR']:+.2f}, mean margin {after['mean margin'] - before['mean margin']:+.2f}"
    asks = f"(a) asks {args.gain:+g}, (b) " + (f"a mean margin of {args.keep_margin:+g} or more" if args.keep_margin is not None else f"{args.gain:+g}")
    print(f"\nrule {'met' if not failed else 'not met: ' + '; '.join(failed)} ({gains}; {asks})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
