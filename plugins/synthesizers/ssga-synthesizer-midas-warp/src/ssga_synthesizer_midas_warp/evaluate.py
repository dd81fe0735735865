"""Depth figures of a MiDaS network: AbsRel and delta < 1.25 on held-out homes and on Middlebury.

Two ways of making the prediction metric, both reported:

* ``calibrated``: the global ``1 / z = s * pred + t`` stored beside the weights, what the
  synthesizer uses (no truth needed at run time);
* ``aligned``: ``(s, t)`` fitted per image to its own true inverse depth by least
  squares, MiDaS's evaluation protocol: how good the *relative* depth is, the best any
  calibration could do.

Metrics, per image on its valid pixels and then averaged over images: AbsRel
``mean(|z - z*| / z*)`` and delta1 the share of pixels with ``max(z / z*, z* / z) < 1.25``;
depths are clamped to the synthesizer's ``depth_range`` first.

Middlebury 2014 "Motorcycle" as scikit-image ships it (``skimage.data.stereo_motorcycle()``,
741 x 500, the left image): depth ``z = B f / (d + doffs)`` with f = 994.978 px,
B = 193.001 mm, doffs = 31.086 px (calib.txt / 4); missing disparity (+inf) is excluded.

    python -m ssga_synthesizer_midas_warp.evaluate [--weights FILE]
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ssga_synthesizer_midas_warp.calibration import Calibration, align_per_image, minmax_depth, to_depth

MIDDLEBURY_F = 994.978
MIDDLEBURY_B_MM = 193.001
MIDDLEBURY_DOFFS = 31.086
DEPTH_RANGE = (0.2, 20.0)
"""The synthesizer's default clamp."""


def middlebury() -> tuple[np.ndarray, np.ndarray]:
    """``(rgb (500, 741, 3) uint8, depth (500, 741) float32 metres, 0 where unknown)`` of the left camera."""
    from skimage.data import stereo_motorcycle

    left, _, disparity = stereo_motorcycle()
    disparity = np.asarray(disparity, dtype=np.float64)
    known = np.isfinite(disparity)
    depth = np.where(known, MIDDLEBURY_B_MM * MIDDLEBURY_F / (np.where(known, disparity, 0.0) + MIDDLEBURY_DOFFS) / 1000.0, 0.0)
    return np.ascontiguousarray(left), depth.astype(np.float32)


def depth_errors(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """``(AbsRel, delta1)`` of one image on ``mask``."""
    z, t = estimate[mask].astype(np.float64), truth[mask].astype(np.float64)
    ratio = np.maximum(z / t, t / z)
    return float(np.mean(np.abs(z - t) / t)), float(np.mean(ratio < 1.25))


def evaluate_predictions(
    preds: np.ndarray, depths: np.ndarray, calibration: Calibration | None, depth_range: tuple[float, float] = DEPTH_RANGE
) -> dict[str, dict[str, float]]:
    """AbsRel and delta1 of predictions ``(N, H, W)`` against true depths (``<= 0`` unknown), each way of making them metric."""
    rows: dict[str, list[tuple[float, float]]] = {"aligned": [], "minmax": []}
    if calibration is not None:
        rows["calibrated"] = []
    scales = []
    for pred, depth in zip(preds, depths):
        mask = np.isfinite(depth) & (depth > 0)
        if mask.sum() < 2:
            continue
        s, t = align_per_image(pred, depth, mask)
        scales.append((s, t))
        rows["aligned"].append(depth_errors(to_depth(s * pred.astype(np.float64) + t, depth_range), depth, mask))
        rows["minmax"].append(depth_errors(minmax_depth(pred, depth_range), depth, mask))
        if calibration is not None:
            rows["calibrated"].append(depth_errors(calibration.depth(pred, depth_range), depth, mask))
    out = {k: {"abs_rel": float(np.mean([r[0] for r in v])), "delta1": float(np.mean([r[1] for r in v])), "images": len(v)} for k, v in rows.items()}
    st = np.array(scales)
    out["per_image_fit"] = {
        "scale_median": float(np.median(st[:, 0])),
        "scale_iqr": [float(q) for q in np.percentile(st[:, 0], [25, 75])],
        "shift_median": float(np.median(st[:, 1])),
        "shift_iqr": [float(q) for q in np.percentile(st[:, 1], [25, 75])],
    }
    return out


def evaluate_network(net: Any, calibration: Calibration | None, heldout_rgb: np.ndarray, heldout_depth: np.ndarray, *, batch: int = 16) -> dict[str, Any]:
    """The held-out homes' figures and Middlebury's for ``net`` (a :class:`~.model.MidasNet`)."""
    from ssga_synthesizer_midas_warp.model import predict

    preds = np.concatenate([predict(net, heldout_rgb[s : s + batch]) for s in range(0, len(heldout_rgb), batch)])
    rgb, depth = middlebury()
    mb_pred = predict(net, [rgb])
    return {
        "heldout_homes": evaluate_predictions(preds, heldout_depth, calibration),
        "middlebury": evaluate_predictions(mb_pred, depth[None], calibration),
    }


def main(argv: Sequence[str] | None = None) -> int:
    """Figures of the packaged (or given) networks on the held-out homes and Middlebury, as JSON."""
    from ssga_bench import evaluation_main
    from ssga_synthesizer_midas_warp.homes import HELDOUT_SEEDS, cached_views
    from ssga_synthesizer_midas_warp.plugin import MidasWarp, MidasWarpConfig

    def arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--network", default=None, choices=["light", "v21-small"], help="default: the weights file's (its keys and shapes)")
        parser.add_argument("--views", type=int, default=50, help="views per held-out home (default 50)")
        parser.add_argument("--cache", type=Path, default=Path("runs/midas-eval"), help="where rendered held-out views are cached")

    def measure(weights: str | None, views: Any, args: argparse.Namespace) -> dict[str, Any]:
        synthesizer = MidasWarp(MidasWarpConfig(network=args.network, device="cpu", **({"weights": weights} if weights else {})))
        return evaluate_network(synthesizer.net, synthesizer.calibration, views.rgb, views.depth)

    return evaluation_main(
        "ssga_synthesizer_midas_warp.evaluate", __doc__, argv,
        held_out=lambda args: cached_views(args.cache, HELDOUT_SEEDS, args.views), measure=measure, add_arguments=arguments,
    )

if __name__ == "__main__":
    sys.exit(main())
