"""Edges by box proximity (paper §3.1.1) and node weights (§3.2)."""

from __future__ import annotations

import numpy as np
import pytest

from ssga_core.graph import node_weights, proximity_edges


def pair(a, b, width=256):
    return proximity_edges(np.array([a, b], dtype=float), width).tolist()


@pytest.mark.parametrize(
    ("b", "joined"),
    [
        ([5, 5, 15, 15], True),  # overlapping
        ([11, 0, 20, 10], True),  # touching pixels: 1 px apart
        ([30, 0, 40, 10], True),  # 20 px gap
        ([31, 0, 40, 10], False),  # 21 px gap
        ([0, 31, 10, 40], False),  # 21 px gap, vertically
        ([24, 24, 30, 30], True),  # nearest corners (10, 10) and (24, 24): 19.8 px
    ],
)
def test_boxes_are_close_when_they_overlap_or_are_within_20_px(b, joined):
    a = [0, 0, 10, 10]
    assert (pair(a, b) == [[0, 1]]) is joined


def test_diagonal_gap_is_euclidean():
    assert pair([0, 0, 10, 10], [25, 25, 30, 30]) == []  # 21.2 px


def test_gap_scales_with_image_width():
    assert pair([0, 0, 10, 10], [50, 0, 60, 10], width=512) == [[0, 1]]  # 40 px at 512 = 20 px at 256
    assert pair([0, 0, 10, 10], [52, 0, 60, 10], width=512) == []


def test_edges_are_unique_pairs_i_lt_j():
    boxes = np.array([[0, 0, 255, 255], [0, 0, 10, 10], [200, 200, 210, 210], [5, 5, 8, 8]], float)
    assert proximity_edges(boxes, 256).tolist() == [[0, 1], [0, 2], [0, 3], [1, 3]]


def test_whole_image_weighs_one_and_each_part_one_over_k():
    np.testing.assert_allclose(node_weights(4), [1, 0.25, 0.25, 0.25, 0.25])
    np.testing.assert_allclose(node_weights(0), [1])
