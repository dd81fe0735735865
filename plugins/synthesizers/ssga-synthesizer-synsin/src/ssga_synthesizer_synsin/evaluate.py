"""How close are synthesized views to true renders? Held-out homes, synsin against depth-warp on true depth.

Pairs: ``pairs_per_home`` orbit pairs (:mod:`.pairs`) in each held-out home (3100, 3101:
no training run and no benchmark uses them). Each pair's source view is synthesized at
the target pose and compared with the true render there, as the repository's
``scripts/synthesis_quality.py`` measures (the same masks and scores,
:mod:`ssga_bench.synthesis_quality`):

* ``seen``: target pixels whose true surface the source saw (the pixel, moved into the
  source camera with the true target depth, lands on the source's true depth there
  within 2%, read at the nearest pixel or bilinearly as inverse depth). A seen pixel the
  synthesis left empty counts (as black). The content a synthesis can hope to get right.
* ``image``: every pixel (what no source saw must be invented: a learned synthesizer
  paints it, depth-warp leaves wide holes black).

Scores pool all pairs' masked pixels: PSNR of the mean squared error, and SSIM
(scikit-image, Gaussian window sigma 1.5, per channel) averaged over the masked pixels,
the synthetic image taking the true pixels outside the mask. Synthesizers:

* ``synsin``: what the plugin renders from RGB alone (its predicted depth);
* ``depth-warp (true depth)``: the depth-warp plugin with the true source depth, the
  geometric upper reference;
* ``synsin (true depth)``: the same network, its depth replaced by the true one, which
  separates the depth predictor's errors from the splatting and refinement's;
* ``source as is``: the unmoved source image (a floor any synthesizer must beat).

Also the depth predictor's error on the source views (median absolute relative error,
and the share within 10%).

    python -m ssga_synthesizer_synsin.evaluate [--weights FILE] [--pairs-per-home 40] [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ssga_bench import QualityTally, seen_mask
from ssga_synthesizer_synsin.pairs import HELDOUT_SEEDS, Pairs, render_pairs


@dataclass(frozen=True)
class HeldOut:
    seeds: tuple[int, ...] = HELDOUT_SEEDS
    pairs_per_home: int = 40
    distance_m: tuple[float, float] = (0.6, 1.4)
    max_turn_deg: float = 60.0


def render_heldout(spec: HeldOut = HeldOut(), progress: Callable[[str], None] | None = None) -> Pairs:
    return Pairs.concat(
        [
            render_pairs(s, spec.pairs_per_home, distance_m=spec.distance_m, max_turn_deg=spec.max_turn_deg, progress=progress)
            for s in spec.seeds
        ]
    )


@dataclass
class Scores:
    seen: QualityTally = field(default_factory=QualityTally)
    image: QualityTally = field(default_factory=QualityTally)
    pairs: int = 0
    seconds: float = 0.0

    def row(self) -> dict[str, float]:
        return {
            "pairs": self.pairs,
            "seen_psnr": round(self.seen.psnr, 2),
            "seen_ssim": round(self.seen.ssim, 4),
            "image_psnr": round(self.image.psnr, 2),
            "image_ssim": round(self.image.ssim, 4),
            "ms_per_view": round(1000 * self.seconds / max(self.pairs, 1), 1),
        }


def views(pairs: Pairs, i: int):
    """The source and target :class:`~ssga_core.View` of pair ``i`` (with true depth)."""
    from ssga_core import View

    return tuple(View(rgb=pairs.rgb[i, k], pose=pairs.pose(i, k), depth=pairs.depth[i, k].astype(np.float32)) for k in (0, 1))


def measure(renderers: dict[str, Callable[[Any, Any], np.ndarray]], pairs: Pairs) -> dict[str, dict[str, float]]:
    """Scores of each renderer ``(source view, target pose) -> (H, W, 3) uint8`` on every pair."""
    scores = {name: Scores() for name in renderers}
    for i in range(len(pairs)):
        source, truth = views(pairs, i)
        seen = seen_mask(truth, [source])
        everything = np.ones_like(seen)
        for name, render in renderers.items():
            t = time.perf_counter()
            rgb = render(source, truth.pose)
            scores[name].seconds += time.perf_counter() - t
            scores[name].seen.add(rgb, truth.rgb, seen)
            scores[name].image.add(rgb, truth.rgb, everything)
            scores[name].pairs += 1
    return {name: s.row() for name, s in scores.items()}


def depth_errors(predict: Callable[[Any], np.ndarray], pairs: Pairs) -> dict[str, float]:
    """Median absolute relative error of predicted source depths, and the share of pixels within 10%."""
    errors = []
    for i in range(len(pairs)):
        source, _ = views(pairs, i)
        known = source.depth > 0
        pred = predict(source)
        errors.append(np.abs(pred[known] - source.depth[known]) / source.depth[known])
    e = np.concatenate(errors)
    return {"median_abs_rel": round(float(np.median(e)), 4), "within_10pct": round(float((e < 0.1).mean()), 4)}


def synsin_renderers(synthesizer) -> dict[str, Callable[[Any, Any], np.ndarray]]:
    """``synsin`` (predicted depth) and ``synsin (true depth)`` renderers of a :class:`SynSinSynthesizer`."""
    import torch

    from ssga_synthesizer_synsin.model import normalise, render, to_uint8

    net = synthesizer.net

    def own(source, target):
        return synthesizer.synthesize(source, target).view.rgb

    def true_depth(source, target):
        T = torch.from_numpy(target.relative_to(source.pose)).float()[None]
        K = torch.from_numpy(source.camera.K).float()
        with torch.inference_mode():
            out, _, _ = render(net, normalise(source.rgb), K, T, depth=torch.from_numpy(source.depth)[None, None].float())
        return to_uint8(out)[0]

    return {"synsin": own, "synsin (true depth)": true_depth}


def reference_renderers() -> dict[str, Callable[[Any, Any], np.ndarray]]:
    """``depth-warp (true depth)`` (the installed plugin, its defaults) and ``source as is``."""
    from ssga_core.cli import current_registry

    from ssga_core import resolve_stage

    warp = resolve_stage("synthesizer", {"name": "depth-warp"}, current_registry()).create()
    return {
        "depth-warp (true depth)": lambda source, target: warp.synthesize(source, target).view.rgb,
        "source as is": lambda source, target: source.rgb,
    }


def evaluate(synthesizer, pairs: Pairs, *, references: bool = True) -> dict[str, Any]:
    """Every score of the module docstring for one synthesizer (a :class:`SynSinSynthesizer`)."""
    renderers = synsin_renderers(synthesizer)
    if references:
        renderers.update(reference_renderers())
    return {"scores": measure(renderers, pairs), "depth": depth_errors(synthesizer.predict_depth, pairs), "pairs": len(pairs)}


def table(rows: dict[str, dict[str, float]]) -> str:
    lines = ["| | seen PSNR | seen SSIM | image PSNR | image SSIM | ms/view |", "|---|---|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(
            f"| {name} | {r['seen_psnr']:.2f} | {r['seen_ssim']:.3f} | {r['image_psnr']:.2f} | {r['image_ssim']:.3f} | {r['ms_per_view']:.0f} |"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    from ssga_bench import evaluation_main
    from ssga_synthesizer_synsin.plugin import SynSinConfig, SynSinSynthesizer

    def arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--pairs-per-home", type=int, default=HeldOut.pairs_per_home)

    def measure(weights: str | None, pairs: Pairs, args: argparse.Namespace) -> dict[str, Any]:
        first = weights == (args.weights or [None])[0]  # the reference renderers are scored once, beside the first
        figures = evaluate(SynSinSynthesizer(SynSinConfig(weights=weights or "synsin-light.pt", device="cpu")), pairs, references=first)
        print(table(figures["scores"]))
        return figures

    return evaluation_main(
        "ssga_synthesizer_synsin.evaluate", __doc__, argv,
        held_out=lambda args: render_heldout(HeldOut(pairs_per_home=args.pairs_per_home)), measure=measure, add_arguments=arguments,
    )

if __name__ == "__main__":
    sys.exit(main())
