"""The feature cache gives back what a parser produced, attributes and all, from memory and from disk."""

from __future__ import annotations

import dataclasses

import numpy as np

from ssga_bench.cache import FeatureCache
from ssga_core.testing.stages import StripesParser
from ssga_core.testing.views import make_view


class NamedStripes(StripesParser):
    """Stripes with a class name and a score each, as a segmenter or detector gives them."""

    def _parse(self, view):
        regions = super()._parse(view)
        k = len(regions)
        return dataclasses.replace(regions, names=tuple(f"stripe {i}" for i in range(k)), scores=np.linspace(0.1, 0.9, k, dtype=np.float32))


def test_region_names_and_scores_survive_the_disk_cache(tmp_path):
    view = make_view()
    parser = NamedStripes(NamedStripes.Config(stripes=3))
    first = FeatureCache(tmp_path).regions(parser, view)
    again = FeatureCache(tmp_path).regions(parser, view)  # a fresh cache reads the .npz
    assert list(tmp_path.rglob("*.npz"))
    assert again.names == first.names == ("stripe 0", "stripe 1", "stripe 2")
    np.testing.assert_array_equal(again.scores, first.scores)
    np.testing.assert_array_equal(again.labels, first.labels)
