"""Speed of the scene parsers (``make bench``): milliseconds per 256 x 256 image.

Two images: ``make_view``'s painted wall (flat rectangles on a gradient, what the
tests use) and scikit-image's astronaut photograph resized to 256 x 256 (real texture,
shipped with scikit-image). SLICO runs at its default and at each preset; the
semantic parser on the painted wall's ids, grouped by instance and by category.
Run alone with ``pytest benchmarks/bench_parsers.py -o python_files='bench_*.py' --benchmark-enable``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("ssga_parser_slico")
pytest.importorskip("ssga_parser_semantic")

import cv2  # noqa: E402
from ssga_parser_semantic.plugin import SemanticConfig, SemanticParser  # noqa: E402
from ssga_parser_slico.plugin import SlicoConfig, SlicoParser  # noqa: E402

from ssga_core import View  # noqa: E402
from ssga_core.testing import make_view  # noqa: E402


def _photo() -> View:
    import skimage.data

    rgb = cv2.resize(skimage.data.astronaut(), (256, 256), interpolation=cv2.INTER_AREA)
    return dataclasses.replace(make_view(), rgb=np.ascontiguousarray(rgb))


IMAGES = {"painted": make_view, "photo": _photo}


def _ms_per_image(benchmark, regions: int) -> None:
    benchmark.extra_info["regions"] = regions
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        benchmark.extra_info["ms_per_image"] = round(1000 * stats.stats.median, 2)


@pytest.mark.parametrize("image", sorted(IMAGES))
@pytest.mark.parametrize("preset", ["default", "coarse", "fine"])
def test_slico(benchmark, preset, image):
    """SLICO at 256 x 256: ~41 ms of CPU per image at the default (64 superpixels) on the 2-core
    dev machine, ~36 coarse, ~44 fine; wall clock doubles while other jobs share the machine."""
    parser = SlicoParser(SlicoConfig(**SlicoParser.presets.get(preset, {})))
    view = IMAGES[image]()
    regions = benchmark(parser.parse, view)
    _ms_per_image(benchmark, len(regions))


@pytest.mark.parametrize("image", sorted(IMAGES))
def test_slico_five_iterations(benchmark, image):
    """Half the k-means iterations: the cheapest way to buy speed."""
    parser = SlicoParser(SlicoConfig(max_iterations=5))
    regions = benchmark(parser.parse, IMAGES[image]())
    _ms_per_image(benchmark, len(regions))


@pytest.mark.parametrize("by", ["instance", "category"])
def test_semantic(benchmark, by):
    """Ground-truth ids to regions: a few milliseconds, mostly np.unique."""
    parser = SemanticParser(SemanticConfig(by=by))
    regions = benchmark(parser.parse, make_view())
    _ms_per_image(benchmark, len(regions))
