#!/usr/bin/env python
"""Do a scene graph's parts tell the GCN anything its whole-image node does not?

For each parser, the query graphs (order PD) of every ``--every``-th test view of a
benchmark dataset, with a descriptor fitted on the dataset's train views, and per graph:

* ``parts``: the number of part nodes;
* ``mean ~ whole``: cosine between the whole-image node's feature and the box-area
  weighted mean of the parts' features. Near 1: the parts' summary, what the default
  readout adds beside the whole image, repeats the whole image;
* ``part ~ whole``: the mean cosine between each part's feature and the whole image's:
  how different the parts are one by one.

    .venv/bin/python scripts/part_summary.py runs/workspaces/procedural-0-40e2f74f --parsers slico,cascade-seg,semantic
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from ssga_bench.dataset import Dataset
from ssga_core.cli import current_registry
from ssga_core.pipeline import BoundVariant, build_graph
from ssga_core.variants import parse_variant

from ssga_core import SsgaError, resolve_stage


def unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True).clip(1e-12)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path, help="a benchmark dataset folder (runs/workspaces/...)")
    parser.add_argument("--parsers", default="slico,cascade-seg,semantic", help="comma-separated parser names")
    parser.add_argument("--descriptor", default="dense-sift")
    parser.add_argument("--every", type=int, default=50, help="every N-th test view")
    parser.add_argument("--views", type=int, default=30, help="at most this many test views")
    args = parser.parse_args(argv)
    try:
        registry = current_registry()
        dataset = Dataset.open(args.dataset)
        descriptor = resolve_stage("descriptor", {"name": args.descriptor}, registry).create()
        descriptor.fit([dataset.view(s) for s in dataset.split("train")])
        tests = [dataset.view(s) for s in dataset.split("test")[:: args.every][: args.views]]
        print(f"{len(tests)} test views of {args.dataset}, descriptor {args.descriptor}\n")
        print("| parser | parts | mean ~ whole | part ~ whole |\n|---|---:|---:|---:|")
        for name in args.parsers.split(","):
            bound = BoundVariant(parse_variant("PD"), descriptor, resolve_stage("parser", {"name": name}, registry).create())
            parts, summary, single = [], [], []
            for view in tests:
                graph = build_graph(bound, view)
                whole, features, boxes = graph.features[0].astype(np.float64), graph.features[1:].astype(np.float64), graph.boxes[1:]
                if not len(features):
                    continue
                area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
                mean = (features * area[:, None]).sum(axis=0) / area.sum()
                parts.append(len(features))
                summary.append(float(unit(mean) @ unit(whole)))
                single.append(float((unit(features) @ unit(whole)).mean()))
            print(f"| {name} | {np.mean(parts):.1f} | {np.mean(summary):.3f} | {np.mean(single):.3f} |")
    except SsgaError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
