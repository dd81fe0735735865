"""Held-out figures of a segmenter on procedural homes: pixel accuracy, per-class IoU, mIoU.

    python -m ssga_parser_cascade_seg.evaluate [--preset NAME] [--weights FOLDER] [--image-sizes 176,216,256,296,336]

As CSAIL's ``eval.py`` counts them: over every labelled pixel of every view (unknown
pixels, ``-1``, are left out), a class's IoU is its intersection over its union summed
over the views; mIoU is their mean over the classes that occur (in the truth or the
prediction); pixel accuracy is the share of labelled pixels predicted right.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ssga_parser_cascade_seg.homes import HELDOUT_SEEDS, Labelled, cached_labelled


def confusion(pred: np.ndarray, truth: np.ndarray, num_class: int) -> np.ndarray:
    """``(C, C)`` counts of (true class, predicted class) over the pixels whose truth is known."""
    known = truth >= 0
    pairs = truth[known].astype(np.int64) * num_class + pred[known].astype(np.int64)
    return np.bincount(pairs, minlength=num_class * num_class).reshape(num_class, num_class)


def scores(counts: np.ndarray, names: Sequence[str]) -> dict[str, Any]:
    """Pixel accuracy, mIoU and each class's IoU (``None`` where the class never occurs) from a confusion matrix."""
    intersection = np.diag(counts).astype(np.float64)
    union = counts.sum(0) + counts.sum(1) - intersection
    occurs = union > 0
    iou = np.where(occurs, intersection / np.maximum(union, 1), np.nan)
    return {
        "pixel_accuracy": round(float(intersection.sum() / max(counts.sum(), 1)), 4),
        "mean_iou": round(float(np.nanmean(iou)), 4) if occurs.any() else None,
        "iou": {name: (round(float(v), 4) if ok else None) for name, v, ok in zip(names, iou, occurs, strict=True)},
        "pixels": {name: int(n) for name, n in zip(names, counts.sum(1), strict=True)},
    }


def evaluate(classify: Callable[[np.ndarray], np.ndarray], data: Labelled, names: Sequence[str]) -> dict[str, Any]:
    """:func:`scores` of ``classify`` (an ``(H, W, 3)`` uint8 image -> ``(H, W)`` class indices) on ``data``."""
    counts = np.zeros((len(names), len(names)), dtype=np.int64)
    start = time.perf_counter()
    for rgb, truth in zip(data.rgb, data.labels, strict=True):
        counts += confusion(classify(rgb), truth, len(names))
    return {**scores(counts, names), "views": len(data), "homes": sorted({int(h) for h in data.home}), "seconds": round(time.perf_counter() - start, 1)}


def main(argv: Sequence[str] | None = None) -> int:
    from ssga_bench import evaluation_main
    from ssga_core import resolve_stage
    from ssga_core.cli import current_registry

    def arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--preset", default=None, help="one of the parser's presets (default: its defaults, the packaged light network)")
        parser.add_argument("--image-sizes", default=None, help="comma-separated test scales, e.g. 176,216,256,296,336 (default: the preset's)")
        parser.add_argument("--views", type=int, default=50, help="views per held-out home (default 50)")
        parser.add_argument("--cache", type=Path, default=Path("runs/cascade-seg-views"), help="folder of the rendered views")

    def measure(weights: str | None, data: Labelled, args: argparse.Namespace) -> dict[str, Any]:
        options: dict[str, Any] = {"name": "cascade-seg"}
        if args.preset:
            options["preset"] = args.preset
        if weights:
            options["weights"] = weights
        if args.image_sizes:
            parts = args.image_sizes.split(",")
            # Anything but integers goes to the config as given, which then says what it expected.
            options["image_sizes"] = [int(p) for p in parts] if all(p.strip().isdigit() for p in parts) else args.image_sizes
        segmenter = resolve_stage("parser", options, current_registry(), source="options").create()
        return evaluate(segmenter.classify, data, segmenter.class_names)

    return evaluation_main(
        "ssga_parser_cascade_seg.evaluate", __doc__, argv,
        held_out=lambda args: cached_labelled(args.cache, HELDOUT_SEEDS, args.views), measure=measure, add_arguments=arguments,
    )

if __name__ == "__main__":
    sys.exit(main())
