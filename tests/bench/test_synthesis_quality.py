"""The masks and scores of every synthesis figure (scripts/synthesis_quality.py, the learned synthesizers' held-out figures)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ssga_bench.synthesis_quality import QualityTally, seen_mask
from ssga_core import Pose
from ssga_core.testing import make_view

pytest.importorskip("skimage")


def test_a_sideways_step_along_a_wall_loses_sight_of_one_edge():
    source = make_view(size=96)  # a wall 3 m ahead, hfov 90: 6 m of it in view
    truth = make_view(size=96, pose=Pose(0.0, 0.5, 0.0))  # half a metre to the left
    seen = seen_mask(truth, [source])
    assert seen.mean() == pytest.approx(1 - 0.5 / 6, abs=0.02)
    lost = np.flatnonzero(~seen.all(axis=0))  # the columns not wholly seen lie at one edge
    assert (lost < 12).all() or (lost > 84).all()
    assert seen_mask(truth, [source, truth]).all(), "any source that saw a pixel counts"
    wrong = dataclasses.replace(source, depth=np.full_like(source.depth, 4.0))
    assert not seen_mask(truth, [wrong]).any(), "a surface 1 m off is not the same surface"


def test_psnr_and_ssim_pool_only_the_masked_pixels():
    truth = make_view(size=64).rgb
    mask = np.zeros(truth.shape[:2], dtype=bool)
    mask[:, :32] = True
    exact, off = QualityTally(), QualityTally()
    exact.add(truth.copy(), truth, mask)
    assert exact.psnr == math.inf and exact.ssim == pytest.approx(1.0)
    shifted = truth.astype(np.int16)
    shifted[:, :32] = np.clip(shifted[:, :32] + 10, 0, 255)
    shifted[:, 32:] = 0  # outside the mask: never judged
    clipped = np.clip(truth[:, :32].astype(np.int16) + 10, 0, 255) - truth[:, :32]
    off.add(shifted.astype(np.uint8), truth, mask)
    off.add(shifted.astype(np.uint8), truth, mask)  # pooled: the same pair twice, the same scores
    assert off.pixels == 2 * 64 * 32
    assert off.psnr == pytest.approx(10 * np.log10(255**2 / (clipped.astype(float) ** 2).mean()), rel=1e-9)
    assert 0.5 < off.ssim < 1.0
    assert math.isnan(QualityTally().psnr) and math.isnan(QualityTally().ssim)
