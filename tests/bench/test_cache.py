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


def test_memory_is_bounded_by_the_cache_not_by_the_run(tmp_path, monkeypatch):
    """Real views' entries are read from disk when asked for, never kept; synthetic views'
    are kept for the other variants, the least recently used dropped past the bound."""
    monkeypatch.setattr("ssga_bench.cache.MEMORY_ENTRIES", 3)
    parser = NamedStripes(NamedStripes.Config(stripes=3))
    cache = FeatureCache(tmp_path)
    for seed in range(5):
        cache.regions(parser, make_view(seed=seed))
    assert len(cache._memory) == 0 and len(list(tmp_path.rglob("*.npz"))) == 5
    synthetic = [dataclasses.replace(make_view(seed=10 + seed), synthetic=True) for seed in range(5)]
    for view in synthetic:
        cache.regions(parser, view)
    assert len(cache._memory) == 3 and len(list(tmp_path.rglob("*.npz"))) == 10  # on disk too, for other workers


def test_entries_encoded_by_a_worker_read_back_as_computed_here(tmp_path):
    from ssga_bench.cache import compute_many, encode_entry, stage_key, view_key

    parser = NamedStripes(NamedStripes.Config(stripes=4))
    views = [make_view(seed=s) for s in range(3)]
    cache = FeatureCache(tmp_path)
    for view, arrays in zip(views, compute_many(parser, views)):
        cache.put((stage_key(parser), view_key(view)), encode_entry(arrays))
    for view in views:
        got, want = cache.regions(parser, view), parser.parse(view)
        np.testing.assert_array_equal(got.labels, want.labels)
        assert got.names == want.names
