"""How well the feature reads the room's shape: its correlation with the same feature of the true depth.

For each view, the descriptor's feature (the network's inverse depth of the RGB, on the grid)
against the same feature of the view's true inverse depth: the cosine of the two, on
midas-warp's held-out homes (never trained on, never evaluated by the benchmark), with the
mean cosine against the other views of the same home beside it (rooms share a shape, so this
is far from zero), and the share of views whose own truth is the best match among their home's;
then the same on Middlebury 2014 "Motorcycle" (a real photograph, out of the network's domain).

    python -m ssga_descriptor_depth_layout.evaluate [--weights FILE]
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ssga_core import Camera, Pose, View


def layout_agreement(descriptor: Any, rgb: np.ndarray, depth: np.ndarray, homes: np.ndarray) -> dict[str, float]:
    """Cosines of each view's feature with its true depth's feature, and with the other views' of its home."""
    h, w = rgb.shape[1:3]
    own, others, best = [], [], []
    for home in np.unique(homes):
        index = np.flatnonzero(homes == home)
        truth = np.stack([descriptor.feature(1.0 / np.maximum(depth[i], 0.2)) for i in index])
        estimate = np.stack([descriptor.describe(View(rgb=rgb[i], pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=w, height=h)), None)[0] for i in index])
        likeness = truth @ estimate.T
        own += list(np.diag(likeness))
        others += list(likeness[~np.eye(len(index), dtype=bool)])
        best += list(likeness.argmax(axis=0) == np.arange(len(index)))
    return {
        "views": len(own),
        "own_median": float(np.median(own)),
        "own_mean": float(np.mean(own)),
        "others_mean": float(np.mean(others)) if others else float("nan"),
        "own_best_share": float(np.mean(best)),
    }


def main(argv: Sequence[str] | None = None) -> int:
    """Figures of the packaged (or given) depth network as this descriptor reads it, as JSON."""
    from ssga_bench import evaluation_main
    from ssga_descriptor_depth_layout.plugin import DepthLayout, DepthLayoutConfig
    from ssga_synthesizer_midas_warp.evaluate import middlebury
    from ssga_synthesizer_midas_warp.homes import HELDOUT_SEEDS, cached_views

    def arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--network", default=None, choices=["light", "v21-small"], help="default: the weights file's (its keys and shapes)")
        parser.add_argument("--views", type=int, default=25, help="views per held-out home (default 25)")
        parser.add_argument("--cache", type=Path, default=Path("runs/depth-layout-eval"), help="where rendered held-out views are cached")

    def measure(weights: str | None, views: Any, args: argparse.Namespace) -> dict[str, Any]:
        descriptor = DepthLayout(DepthLayoutConfig(network=args.network, device="cpu", **({"weights": weights} if weights else {})))
        rgb, depth = middlebury()
        photo = np.where(depth > 0, depth, np.median(depth[depth > 0]))  # unknown disparity: the median depth
        return {
            "heldout_homes": layout_agreement(descriptor, views.rgb, views.depth, views.home),
            "middlebury_own": layout_agreement(descriptor, rgb[None], photo[None], np.zeros(1))["own_mean"],
        }

    return evaluation_main(
        "ssga_descriptor_depth_layout.evaluate", __doc__, argv,
        held_out=lambda args: cached_views(args.cache, HELDOUT_SEEDS, args.views), measure=measure, add_arguments=arguments,
    )


if __name__ == "__main__":
    sys.exit(main())
