"""Fit the metric calibration of a MiDaS weights file on procedural homes, and store it beside the file.

    python -m ssga_synthesizer_midas_warp.calibrate --weights midas_v21_small_256.pt

renders ``--views`` RGB-D views of each calibration home (procedural seeds
:data:`~.homes.CALIBRATION_SEEDS`, 2100-2103: never trained on, never evaluated),
predicts their relative inverse depth, and fits ``1 / z = s * pred + t`` robustly
(:func:`~.calibration.fit_inverse_depth`) over ``--pixels`` random valid pixels of each
view. The result, with the SHA-256 of the weights and how it was made, is written to
``<weights stem>.calibration.json`` beside the weights (or ``--out``), where the
synthesizer's ``calibration = "auto"`` finds it, recorded for the network the file holds
(its keys and shapes say which). The training command calls the same :func:`calibrate`
on its exported weights.
"""

from __future__ import annotations

import argparse
import datetime
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ssga_synthesizer_midas_warp.calibration import Calibration, calibration_path, fit_inverse_depth, sha256_file
from ssga_synthesizer_midas_warp.homes import CALIBRATION_SEEDS
from ssga_workspace_procedural.training_homes import bench_and_demo_sized

PIXELS_PER_VIEW = 4096


def calibration_samples(preds: np.ndarray, depths: np.ndarray, pixels: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(pred, 1 / z)`` at ``pixels`` random valid pixels of each view (seeded)."""
    rng = np.random.default_rng([seed, 11])
    xs, ys = [], []
    for pred, depth in zip(preds, depths):
        valid = np.flatnonzero(np.isfinite(depth) & (depth > 0))
        pick = rng.choice(valid, min(pixels, valid.size), replace=False)
        xs.append(pred.ravel()[pick])
        ys.append(1.0 / depth.ravel()[pick].astype(np.float64))
    return np.concatenate(xs), np.concatenate(ys)


def calibrate(
    net: Any,
    network: str,
    weights: str,
    weights_sha256: str,
    rgb: np.ndarray,
    depth: np.ndarray,
    *,
    seeds: Sequence[int],
    pixels: int = PIXELS_PER_VIEW,
    command: str = "",
    seed: int = 0,
) -> Calibration:
    """The calibration of ``net`` (the file ``weights``, whose SHA-256 is given) fitted on views ``rgb`` with true ``depth``."""
    from ssga_synthesizer_midas_warp.model import predict

    preds = np.concatenate([predict(net, rgb[s : s + 16]) for s in range(0, len(rgb), 16)])
    x, y = calibration_samples(preds, depth, pixels, seed)
    fit = fit_inverse_depth(x, y, seed=seed)
    provenance = {
        "what": "1 / z = scale * pred + shift, fitted robustly (least median of squares, then IRLS: Huber, Tukey) on procedural homes",
        "command": command,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "weights": weights,
        "seeds": list(seeds),
        "homes": {str(s): dict(bench_and_demo_sized(s)) for s in seeds},
        "views": len(rgb),
        "pixels_per_view": pixels,
        "fit": {"points": fit.points, "residual_sigma": fit.sigma, "inliers_3sigma": fit.inliers},
    }
    return Calibration(fit.scale, fit.shift, network, weights_sha256, provenance)


def main(argv: Sequence[str] | None = None) -> int:
    import torch

    from ssga_core import SsgaError
    from ssga_synthesizer_midas_warp.homes import cached_views
    from ssga_synthesizer_midas_warp.plugin import MidasWarp, MidasWarpConfig

    parser = argparse.ArgumentParser(prog="python -m ssga_synthesizer_midas_warp.calibrate", description=__doc__.split("\n\n")[0])
    parser.add_argument("--weights", required=True, help="weights file (relative: the plugin's weights/ folder, then here)")
    parser.add_argument("--network", default=None, choices=["light", "v21-small"], help="default: the weights file's (its keys and shapes)")
    parser.add_argument("--views", type=int, default=50, help="views per calibration home (default 50)")
    parser.add_argument("--pixels", type=int, default=PIXELS_PER_VIEW, help=f"pixels per view (default {PIXELS_PER_VIEW})")
    parser.add_argument("--cache", type=Path, default=Path("runs/midas-calibration"), help="where rendered views are cached")
    parser.add_argument("--out", type=Path, default=None, help="calibration file (default: <weights stem>.calibration.json beside the weights)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        synthesizer = MidasWarp(MidasWarpConfig(weights=args.weights, network=args.network, calibration="minmax", device="cpu"))
        weights = synthesizer.weights_file(Path(__file__).parent / "weights").resolve()
        views = cached_views(args.cache, CALIBRATION_SEEDS, args.views, progress=print)
        command = "python -m ssga_synthesizer_midas_warp.calibrate " + shlex.join(sys.argv[1:] if argv is None else list(argv))
        network = synthesizer.config.network  # the file's, resolved when it loaded
        cal = calibrate(synthesizer.net, network, weights.name, sha256_file(weights), views.rgb, views.depth, seeds=CALIBRATION_SEEDS, pixels=args.pixels, command=command)
        out = args.out or calibration_path(weights)
        cal.write(out)
    except SsgaError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"{out}: 1 / z = {cal.scale:.6g} * pred + {cal.shift:.6g} ({cal.provenance['fit']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
