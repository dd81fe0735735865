"""Speed of the dense-SIFT descriptor and of the bag-of-words step every local descriptor shares (``make bench``).

* extraction: 144 SIFT descriptors on Patch-NetVLAD's 12 x 12 grid of a 256 x 256 view;
* dictionary: k-means k = 100 plus the prototype draw on ~50k real dense-SIFT descriptors
  (348 views of :func:`ssga_core.testing.make_view`);
* encode + pool: one scene graph's node features (whole image + 16 parts) from its
  144 local features, NBNN (the default) and centroid similarity.

Run alone with ``pytest benchmarks/bench_descriptors.py -o python_files=bench_*.py --benchmark-enable``.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ssga_descriptor_dense_sift")

from ssga_descriptor_dense_sift.plugin import DenseSift, DenseSiftConfig  # noqa: E402

from ssga_bench import BagOfWords, BoWConfig  # noqa: E402
from ssga_core.testing import make_view  # noqa: E402

TRAIN_VIEWS = 348  # x 144 = 50,112 descriptors


@pytest.fixture(scope="module")
def train_descriptors() -> np.ndarray:
    d = DenseSift()
    return np.concatenate([d.extract(make_view(seed=s)).descriptors for s in range(TRAIN_VIEWS)])


def _ms_per_item(benchmark, items: int, key: str) -> None:
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        benchmark.extra_info[key] = round(1000 * stats.stats.median / items, 3)


@pytest.mark.parametrize("root_sift", [False, True])
def test_dense_sift_extract(benchmark, root_sift):
    """One 256 x 256 view: ~2-4 ms measured on the 2-core dev machine (OpenCV describes at the keypoint's octave)."""
    d = DenseSift(DenseSiftConfig(root_sift=root_sift))
    view = make_view(seed=0)
    local = benchmark(d.extract, view)
    assert local.descriptors.shape == (144, 128)
    _ms_per_item(benchmark, 1, "ms_per_image")


def test_bow_fit_k100_on_50k(benchmark, train_descriptors):
    """k-means++ and Lloyd (numpy, float32 BLAS) plus the prototype draw."""
    benchmark.extra_info["descriptors"] = len(train_descriptors)
    bow = benchmark.pedantic(lambda: BagOfWords(BoWConfig()).fit(train_descriptors), rounds=3, warmup_rounds=1)
    assert bow.centroids.shape == (100, 128)


@pytest.mark.parametrize("similarity", ["nbnn", "centroid"])
def test_encode_and_pool_one_graph(benchmark, train_descriptors, similarity):
    """144 local features to 17 node features (whole image + a 4 x 4 grid of parts)."""
    d = DenseSift(DenseSiftConfig(bow=BoWConfig(similarity=similarity)))
    d.bow.fit(train_descriptors)
    local = d.extract(make_view(seed=TRAIN_VIEWS + 1))
    cell = (local.positions[:, 1] // 64 * 4 + local.positions[:, 0] // 64).astype(int)
    members = [np.arange(len(local)), *(np.flatnonzero(cell == c) for c in range(16))]
    nodes = benchmark(d.pool, local, members)
    assert nodes.shape == (17, 100)
    _ms_per_item(benchmark, 1, "ms_per_graph")
