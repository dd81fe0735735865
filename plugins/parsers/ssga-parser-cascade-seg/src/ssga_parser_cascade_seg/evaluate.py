"""Held-out figures of a segmenter on procedural homes: pixel accuracy, per-class IoU, mIoU.

    python -m ssga_parser_cascade_seg.evaluate [--preset NAME] [--weights FOLDER] [--image-sizes 176,216,256,296,336] [--pieces 0.5,0.7,0.8]

As CSAIL's ``eval.py`` counts them: over every labelled pixel of every view (unknown
pixels, ``-1``, are left out), a class's IoU is its intersection over its union summed
over the views; mIoU is their mean over the classes that occur (in the truth or the
prediction); pixel accuracy is the share of labelled pixels predicted right. With
``--pieces``, also how often a parsed piece's class is right by its score (:func:`piece_reliability`).
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


def piece_reliability(
    probabilities: Callable[[np.ndarray], np.ndarray],
    data: Labelled,
    names: Sequence[str],
    thresholds: Sequence[float],
    min_px: int = 64,
    connectivity: int = 8,
) -> dict[str, Any]:
    """How often a parsed piece's class is right, by how sure the network is of it.

    Each view is parsed into pieces as the parser parses it (:func:`.plugin.class_regions`:
    ``probabilities`` an ``(H, W, 3)`` uint8 image -> ``(C, H, W)``); a piece is right when its class
    is the most frequent true class of its labelled pixels (a piece of none is left out), and its
    score is its mean probability of its class (``Regions.scores``). For each threshold: the share of
    pieces scored at or above it and the share right among those, over all pieces and per predicted
    class (what ``[training] match_category_min_score`` keeps)."""
    from ssga_parser_cascade_seg.plugin import class_regions

    predicted, right, score = [], [], []
    for rgb, truth in zip(data.rgb, data.labels, strict=True):
        probs = probabilities(rgb)
        regions = class_regions(probs.argmax(0).astype(np.int32), tuple(names), min_px, connectivity, probs.max(0))
        assert regions.categories is not None and regions.scores is not None
        labelled = (regions.labels >= 0) & (truth >= 0)
        votes = np.zeros((len(regions), len(names)), np.int64)
        np.add.at(votes, (regions.labels[labelled], truth[labelled].astype(np.int64)), 1)
        has = votes.sum(1) > 0
        predicted.extend(regions.categories[has].tolist())
        right.extend((votes[has].argmax(1) == regions.categories[has]).tolist())
        score.extend(regions.scores[has].tolist())
    cls, ok, sc = np.asarray(predicted, np.int64), np.asarray(right, bool), np.asarray(score, np.float64)

    def summary(among: np.ndarray) -> dict[str, Any]:
        out: dict[str, Any] = {"pieces": int(among.sum()), "right": round(float(ok[among].mean()), 4) if among.any() else None}
        for t in thresholds:
            kept = among & (sc >= t)
            out[f"at {t:g}"] = {
                "kept": round(float(kept.sum() / max(among.sum(), 1)), 4),
                "right": round(float(ok[kept].mean()), 4) if kept.any() else None,
            }
        return out

    return {"all": summary(np.ones(len(cls), bool)), "classes": {name: summary(cls == k) for k, name in enumerate(names) if (cls == k).any()}}


def _thresholds(text: str) -> list[float]:
    try:
        values = [float(t) for t in text.split(",")]
    except ValueError:
        values = []
    if not values or not all(0 <= v <= 1 for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated mean probabilities in [0, 1] such as 0.5,0.7,0.8, got {text!r}")
    return values


def main(argv: Sequence[str] | None = None) -> int:
    from ssga_bench import evaluation_main
    from ssga_core import resolve_stage
    from ssga_core.cli import current_registry

    def arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--preset", default=None, help="one of the parser's presets (default: its defaults, the packaged light network)")
        parser.add_argument("--image-sizes", default=None, help="comma-separated test scales, e.g. 176,216,256,296,336 (default: the preset's)")
        parser.add_argument("--views", type=int, default=50, help="views per held-out home (default 50)")
        parser.add_argument("--cache", type=Path, default=Path("runs/cascade-seg-views"), help="folder of the rendered views")
        parser.add_argument(
            "--pieces", default=None, type=_thresholds,
            help="also how often a piece's class is right among the pieces scored at or above each of these comma-separated "
            "mean probabilities, e.g. 0.5,0.7,0.8 (for [training] match_category_min_score)",
        )

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
        figures = evaluate(segmenter.classify, data, segmenter.class_names)
        if args.pieces:
            cfg = segmenter.config
            figures["pieces"] = piece_reliability(
                segmenter.probabilities, data, segmenter.class_names, args.pieces, cfg.min_region_px, cfg.connectivity  # type: ignore[attr-defined]
            )
        return figures

    return evaluation_main(
        "ssga_parser_cascade_seg.evaluate", __doc__, argv,
        held_out=lambda args: cached_labelled(args.cache, HELDOUT_SEEDS, args.views), measure=measure, add_arguments=arguments,
    )

if __name__ == "__main__":
    sys.exit(main())
