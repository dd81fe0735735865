"""detic in batches: ``parse_many`` gives each view what ``parse`` gives it (detic parses a batch one view
at a time, on purpose: the comment after ``DeticParser._parse`` says why)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from ssga_core.testing import make_view
from ssga_parser_detic.plugin import DeticConfig, DeticParser


def _assert_same(many, views, parser: DeticParser) -> None:
    for view, got in zip(views, many, strict=True):
        one = parser.parse(view)
        np.testing.assert_array_equal(got.labels, one.labels)
        np.testing.assert_array_equal(got.categories, one.categories)
        assert got.names == one.names
        # Measured on the CPU (one torch thread): boxes and scores differ by 0.0 (each view is its own call).
        np.testing.assert_allclose(got.boxes, one.boxes, rtol=0, atol=1e-5)
        np.testing.assert_allclose(got.scores, one.scores, rtol=0, atol=1e-6)


def test_a_batch_gives_each_view_its_single_regions(vocabulary):
    # test_size 96: a parse takes about 0.5 s here and random weights still find 2-3 detections a view.
    parser = DeticParser(DeticConfig(weights="random", device="cpu", test_size=96, max_detections=3, **vocabulary))
    views = [make_view(seed=1), make_view(seed=2), make_view(seed=3, size=200)]
    many = parser.parse_many(views)
    assert all(len(regions) > 0 for regions in many)
    _assert_same(many, views, parser)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_on_cuda_a_batch_gives_each_view_its_single_regions(vocabulary):
    parser = DeticParser(DeticConfig(weights="random", device="cuda", test_size=256, max_detections=6, **vocabulary))
    views = [make_view(seed=1), make_view(seed=2), make_view(seed=3, size=200)]
    _assert_same(parser.parse_many(views), views, parser)
