"""How close are a synthesizer's views to true renders at the same poses?

Protocol. A rendered benchmark dataset has, per cell, one real view with depth (split
``train``) and true renders at the canonical viewpoints of the cell's other classes
(split ``target``, an oracle the method never trains on). Rendering each train view at
its cell's targets is exactly the synthesis the method does, and each synthetic view is
compared with the true render at its pose.

Masks, per pair:

* ``seen``: the target pixels whose true surface the source view saw: the pixel, moved
  into the source camera with the true render's depth, lands on the source's own depth
  there (within 2%). It does not depend on the synthesizer, so configurations are
  compared on the same pixels, and a seen pixel the synthesis left empty counts (as
  black). This is the content a synthesis can hope to get right.
* ``drawn``: the pixels the synthesis drew (a point, or a filled hole).
* ``image``: every pixel.

Scores, pooled over all pairs (each masked pixel counts once): PSNR of the mean squared
error, and SSIM (scikit-image's ``structural_similarity``: Gaussian window, sigma 1.5,
per colour channel) averaged over the masked pixels. For a mask, the synthetic image
takes the true render's pixels outside it, so that an SSIM window straddling the mask's
edge judges only the masked pixels. ``seen cov`` is the share of seen pixels the
synthesis drew. ``vis P/R`` judge the point map (what carries features and regions):
of the source pixels marked visible, the share truly visible (their depth in the target
within 2% of the true render's at their pixel), and of those truly visible, the share
marked so.

Multi-source: each target is also rendered from the train views of all cells at once
(``synthesize_from``), and, for comparison, with the core's default way of doing that
(each view alone, composed by depth). ``ms`` is the time to render one target.

Everything is deterministic; ``--pairs N`` draws a subset with ``--seed``. From the
repository root::

    .venv/bin/python scripts/synthesis_quality.py
    .venv/bin/python scripts/synthesis_quality.py -p splat=2 -p fill_holes=none --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from ssga_bench.dataset import Dataset
from ssga_bench.synthesis_quality import QualityTally, move, on_surface, seen_mask
from ssga_core.config import resolve_stage
from ssga_core.plugins import default_registry
from ssga_core.stages import fuse_syntheses

from ssga_core import Pose, SsgaError, Synthesis, Synthesizer, View

DEFAULT_DATASET = Path("runs/workspaces/procedural-0-dd0941a0")
def drawn_mask(view: View) -> np.ndarray:
    """The pixels a synthesis drew: a depth, or a colour (filled holes keep depth 0)."""
    drawn = view.rgb.any(axis=-1)
    if view.depth is not None:
        drawn |= view.depth > 0
    return drawn


@dataclass
class Report:
    """The scores of one way of synthesizing, over all its (sources, target) pairs."""

    seen: QualityTally = field(default_factory=QualityTally)
    drawn: QualityTally = field(default_factory=QualityTally)
    image: QualityTally = field(default_factory=QualityTally)
    pairs: int = 0
    pixels: int = 0
    seen_drawn: int = 0
    marked: int = 0
    marked_true: int = 0
    truly: int = 0
    seconds: float = 0.0

    def add(self, syntheses: Sequence[Synthesis], sources: Sequence[View], truth: View) -> None:
        synthetic = syntheses[0].view
        seen, drawn = seen_mask(truth, sources), drawn_mask(synthetic)
        self.seen.add(synthetic.rgb, truth.rgb, seen)
        self.drawn.add(synthetic.rgb, truth.rgb, drawn)
        self.image.add(synthetic.rgb, truth.rgb, np.ones_like(seen))
        self.pairs += 1
        self.pixels += seen.size
        self.seen_drawn += int((seen & drawn).sum())
        for synthesis, source in zip(syntheses, sources, strict=True):
            # The point map's uv with each source pixel's own depth in the target camera.
            truly = on_surface(synthesis.target_uv, move(source.depth, source, truth.pose)[1], truth.depth)
            self.marked += int(synthesis.visible.sum())
            self.marked_true += int((synthesis.visible & truly).sum())
            self.truly += int(truly.sum())

    def row(self) -> dict[str, float]:
        return {
            "pairs": self.pairs,
            "seen_pct": 100 * self.seen.pixels / self.pixels,
            "drawn_pct": 100 * self.drawn.pixels / self.pixels,
            "seen_coverage_pct": 100 * self.seen_drawn / max(self.seen.pixels, 1),
            "seen_psnr": self.seen.psnr,
            "seen_ssim": self.seen.ssim,
            "drawn_psnr": self.drawn.psnr,
            "drawn_ssim": self.drawn.ssim,
            "image_psnr": self.image.psnr,
            "image_ssim": self.image.ssim,
            "visible_precision_pct": 100 * self.marked_true / max(self.marked, 1),
            "visible_recall_pct": 100 * self.marked_true / max(self.truly, 1),
            "ms_per_target": 1000 * self.seconds / max(self.pairs, 1),
        }


WAYS = ("own view", "all views, fused", "all views, composed")
"""How a target is rendered: from its cell's train view; from every cell's, with
``synthesize_from``; from every cell's, each alone and composed by depth (the core's
default ``_synthesize_from``, for comparison)."""


def render(way: str, synthesizer: Synthesizer, own: View, every: list[View], target: Pose) -> tuple[list[Synthesis], list[View]]:
    """The syntheses of ``target`` one of the :data:`WAYS`, and the views they came from."""
    if way == "own view":
        return [synthesizer.synthesize(own, target)], [own]
    if way == "all views, fused":
        return synthesizer.synthesize_from(every, target), every
    return fuse_syntheses([synthesizer.synthesize(view, target) for view in every], synthesizer.name), every


def measure(
    dataset: Dataset, synthesizer: Synthesizer, *, pairs: int | None = None, seed: int = 0
) -> dict[str, dict[str, float]]:
    """Scores of each of the :data:`WAYS` on ``dataset`` (see the module docstring)."""
    train = {s.cell: s for s in dataset.split("train")}
    targets = [t for t in dataset.split("target") if t.cell in train]
    if pairs is not None and pairs < len(targets):
        keep = np.sort(np.random.default_rng(seed).choice(len(targets), pairs, replace=False))
        targets = [targets[i] for i in keep]
    real = {cell: dataset.view(sample) for cell, sample in train.items()}
    every = list(real.values())
    reports = {way: Report() for way in WAYS}
    for sample in targets:
        truth = dataset.view(sample)
        for way, report in reports.items():
            start = time.perf_counter()
            syntheses, sources = render(way, synthesizer, real[sample.cell], every, sample.pose)
            report.seconds += time.perf_counter() - start
            report.add(syntheses, sources, truth)
    return {way: report.row() for way, report in reports.items()}


COLUMNS = [
    ("drawn %", "drawn_pct", ".1f"),
    ("seen %", "seen_pct", ".1f"),
    ("seen cov %", "seen_coverage_pct", ".1f"),
    ("seen PSNR", "seen_psnr", ".2f"),
    ("seen SSIM", "seen_ssim", ".3f"),
    ("drawn PSNR", "drawn_psnr", ".2f"),
    ("drawn SSIM", "drawn_ssim", ".3f"),
    ("image PSNR", "image_psnr", ".2f"),
    ("image SSIM", "image_ssim", ".3f"),
    ("vis P %", "visible_precision_pct", ".1f"),
    ("vis R %", "visible_recall_pct", ".1f"),
    ("ms", "ms_per_target", ".1f"),
]


def table(rows: dict[str, dict[str, float]]) -> str:
    """A Markdown table, one row per way of synthesizing."""
    lines = ["| | pairs | " + " | ".join(c for c, _, _ in COLUMNS) + " |", "|---" * (len(COLUMNS) + 2) + "|"]
    for name, row in rows.items():
        lines.append(f"| {name} | {row['pairs']} | " + " | ".join(format(row[k], f) for _, k, f in COLUMNS) + " |")
    return "\n".join(lines)


def parse_params(items: Sequence[str]) -> dict[str, object]:
    """``KEY=VALUE`` pairs; values are read as JSON where they parse (numbers, booleans), else as strings."""
    params: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"synthesis_quality: expected KEY=VALUE, got {item!r}")
        try:
            params[key] = json.loads(value)
        except json.JSONDecodeError:
            params[key] = value
    return params


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog="See the module docstring for the protocol.")
    parser.add_argument(
        "--dataset", type=Path, default=DEFAULT_DATASET, metavar="DIR", help=f"a rendered dataset (default: {DEFAULT_DATASET})"
    )
    parser.add_argument(
        "--synthesizer", default="depth-warp", metavar="NAME", help="registered synthesizer (default: depth-warp)"
    )
    parser.add_argument("--preset", default=None, metavar="NAME", help="one of the synthesizer's presets to start from")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="KEY=VALUE", help="a config parameter (repeatable)")
    parser.add_argument("--pairs", type=int, default=None, metavar="N", help="score a random subset of N targets (default: all)")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the --pairs draw (default: 0)")
    parser.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write the scores and the config as JSON")
    args = parser.parse_args(argv)
    try:
        ref = {"name": args.synthesizer, **({"preset": args.preset} if args.preset else {}), **parse_params(args.param)}
        stage = resolve_stage("synthesizer", ref, default_registry())
        dataset = Dataset.open(args.dataset)
        rows = measure(dataset, stage.create(), pairs=args.pairs, seed=args.seed)  # type: ignore[arg-type]
    except SsgaError as exc:
        print(f"synthesis_quality: {exc}", file=sys.stderr)
        return 1
    config = stage.config.model_dump()
    print(f"{args.synthesizer} {json.dumps(config)} on {dataset.name}")
    print(table(rows))
    if args.json:
        args.json.write_text(
            json.dumps(
                {"synthesizer": args.synthesizer, "config": config, "dataset": str(args.dataset), "scores": rows}, indent=2
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
