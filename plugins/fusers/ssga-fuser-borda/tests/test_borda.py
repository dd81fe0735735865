from __future__ import annotations

import numpy as np
import pytest
from ssga_fuser_borda.plugin import BordaCount, MeanProbability

from ssga_core.testing import check_fuser


def test_is_installed(ssga_installed_registry):
    assert {ssga_installed_registry.entry("fuser", n).plugin.distribution for n in ("borda", "mean-prob")} == {"ssga-fuser-borda"}


@pytest.mark.parametrize("fuser", [BordaCount(), MeanProbability()])
def test_meets_the_fuser_contract(fuser):
    check_fuser(fuser)


def test_borda_by_hand():
    scores = np.array([[[0.7, 0.2, 0.1]], [[0.1, 0.5, 0.4]]])
    # C - rank: class 0 gets 2 + 0, class 1 gets 1 + 2, class 2 gets 0 + 1.
    np.testing.assert_array_equal(BordaCount().fuse(scores), [[2, 3, 1]])


def test_borda_tied_classes_take_their_mean_rank():
    scores = np.array([[[0.45, 0.45, 0.10]], [[0.30, 0.60, 0.10]]])
    # Variant 1: classes 0 and 1 share ranks 1 and 2 (1.5 each), class 2 is third.
    np.testing.assert_array_equal(BordaCount().fuse(scores), [[1.5 + 1, 1.5 + 2, 0 + 0]])


def test_mean_probability_by_hand():
    scores = np.array([[[0.7, 0.2, 0.1]], [[0.1, 0.5, 0.4]]])
    np.testing.assert_allclose(MeanProbability().fuse(scores), [[0.4, 0.35, 0.25]])
