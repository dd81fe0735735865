from __future__ import annotations

import numpy as np
import pytest
from ssga_fuser_rrf.plugin import ReciprocalRankFusion, RRFConfig

from ssga_core.testing import check_fuser


def test_is_installed(ssga_installed_registry):
    assert ssga_installed_registry.entry("fuser", "rrf").plugin.distribution == "ssga-fuser-rrf"


@pytest.mark.parametrize("k", [0.0, 60.0])
def test_meets_the_fuser_contract(k):
    check_fuser(ReciprocalRankFusion(RRFConfig(k=k)))


def test_sums_reciprocal_ranks_by_hand():
    # Two variants, one query, three classes.
    scores = np.array([[[0.7, 0.2, 0.1]], [[0.1, 0.5, 0.4]]])
    fused = ReciprocalRankFusion().fuse(scores)
    # Class 0: ranks 1 and 3; class 1: ranks 2 and 1; class 2: ranks 3 and 2.
    np.testing.assert_allclose(fused, [[1 + 1 / 3, 1 / 2 + 1, 1 / 3 + 1 / 2]])


def test_only_ranks_matter_not_calibration():
    scores = np.array([[[0.9, 0.05, 0.05]], [[0.30, 0.36, 0.34]], [[0.2, 0.41, 0.39]]])
    # Mean probability would pick class 0 (one confident variant); two of three variants rank class 1 first.
    assert ReciprocalRankFusion().fuse(scores).argmax() == 1
    assert scores.mean(axis=0).argmax() == 0


def test_bad_scores_are_rejected():
    from ssga_core import InputError

    with pytest.raises(InputError, match=r"expected non-empty \(variants, queries, classes\) scores, got shape \(3, 4\)"):
        ReciprocalRankFusion().fuse(np.zeros((3, 4)))


def test_classes_a_variant_ties_share_its_vote():
    # Variant 1 cannot tell classes 0 and 1 apart (a variant without synthesis scores every
    # heading of its cell alike); variant 2 prefers class 1. By class index, variant 1 would
    # give class 0 a whole vote and class 1 a half, and the fusion would tie at 1.5.
    scores = np.array([[[0.45, 0.45, 0.10]], [[0.30, 0.60, 0.10]]])
    fused = ReciprocalRankFusion().fuse(scores)
    np.testing.assert_allclose(fused, [[0.75 + 0.5, 0.75 + 1.0, 1 / 3 + 1 / 3]])
    assert fused.argmax() == 1
