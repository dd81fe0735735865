"""Ranks and reciprocal ranks, ties broken by position or shared."""

from __future__ import annotations

import numpy as np
import pytest

from ssga_core import ranks, reciprocal_ranks


def test_ordinal_ties_break_by_position():
    assert ranks(np.array([0.2, 0.5, 0.2, 0.1])).tolist() == [2, 1, 3, 4]
    assert reciprocal_ranks(np.array([0.2, 0.5, 0.2, 0.1])).tolist() == [1 / 2, 1, 1 / 3, 1 / 4]


def test_average_ties_share_the_block():
    scores = np.array([0.2, 0.5, 0.2, 0.1])
    assert ranks(scores, ties="average").tolist() == [2.5, 1.0, 2.5, 4.0]
    # Not 1 / 2.5: each tied entry gets the mean of the reciprocal ranks 1/2 and 1/3.
    np.testing.assert_allclose(reciprocal_ranks(scores, ties="average"), [(1 / 2 + 1 / 3) / 2, 1, (1 / 2 + 1 / 3) / 2, 1 / 4])
    np.testing.assert_allclose(reciprocal_ranks(scores, k=60.0, ties="average")[[0, 2]], (1 / 62 + 1 / 63) / 2)


def brute_force(row: np.ndarray, k: float) -> np.ndarray:
    """Each entry's mean of 1 / (k + r) over the ranks r its tied block spans, by counting."""
    above = np.array([(row > x).sum() for x in row])
    tied = np.array([(row == x).sum() for x in row])
    return np.array([np.mean(1.0 / (k + np.arange(a + 1, a + t + 1))) for a, t in zip(above, tied)])


@pytest.mark.parametrize("axis", [0, 1, 2, -1])
@pytest.mark.parametrize("k", [0.0, 60.0])
def test_average_ties_match_counting_on_any_axis(axis, k):
    rng = np.random.default_rng(7)
    scores = rng.integers(0, 4, size=(3, 5, 7)).astype(float)  # many ties
    shared = reciprocal_ranks(scores, k=k, axis=axis, ties="average")
    np.testing.assert_allclose(shared, np.apply_along_axis(brute_force, axis, scores, k))
    # The votes a row hands out do not depend on its ties.
    np.testing.assert_allclose(shared.sum(axis=axis), (1.0 / (k + np.arange(1, scores.shape[axis] + 1))).sum())
    mean_rank = ranks(scores, axis=axis, ties="average")
    np.testing.assert_allclose(mean_rank.sum(axis=axis), scores.shape[axis] * (scores.shape[axis] + 1) / 2)


def test_without_ties_both_rules_agree():
    scores = np.random.default_rng(3).random((4, 9))
    np.testing.assert_array_equal(ranks(scores, ties="average"), ranks(scores))
    np.testing.assert_allclose(reciprocal_ranks(scores, k=5.0, ties="average"), reciprocal_ranks(scores, k=5.0))


def test_an_unknown_tie_rule_is_refused():
    with pytest.raises(ValueError, match="ties must be 'ordinal' or 'average', got 'dense'"):
        ranks(np.array([1.0, 1.0]), ties="dense")  # type: ignore[arg-type]
