"""From relative to metric inverse depth: the robust fit, the clamp, the stored calibration; and the training loss."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from ssga_synthesizer_midas_warp.calibration import Calibration, fit_inverse_depth, minmax_depth, to_depth
from ssga_synthesizer_midas_warp.train import ssi_loss

from ssga_core import InputError


def synthetic(outliers: float, seed: int = 0, n: int = 50_000, s: float = 0.037, t: float = 0.085):
    """Predictions and inverse depths ``s * pred + t`` with 1% noise, a share of them replaced by gross outliers."""
    rng = np.random.default_rng(seed)
    pred = rng.uniform(2.0, 60.0, n)
    inv = (s * pred + t) * (1 + 0.01 * rng.standard_normal(n))
    bad = rng.random(n) < outliers
    inv[bad] = rng.uniform(0.0, 4.0, bad.sum())  # e.g. sky, mirrors, a wrong surface
    return pred, inv


@pytest.mark.parametrize("outliers", [0.0, 0.2, 0.4])
def test_the_fit_recovers_scale_and_shift_despite_outliers(outliers):
    pred, inv = synthetic(outliers)
    fit = fit_inverse_depth(pred, inv)
    assert fit.scale == pytest.approx(0.037, rel=0.01)
    assert fit.shift == pytest.approx(0.085, abs=0.01)
    assert fit.inliers == pytest.approx(1 - outliers, abs=0.05)
    if outliers:  # what plain least squares gets: the outliers matter
        s, _ = np.polyfit(pred, inv, 1)
        assert abs(s / 0.037 - 1) > 0.1


def test_the_fit_refuses_what_it_cannot_fit():
    with pytest.raises(InputError, match="at least 2 points"):
        fit_inverse_depth(np.ones(10), np.arange(10.0))
    with pytest.raises(InputError):
        fit_inverse_depth(np.ones(3), np.ones(4))


def test_depth_is_clamped_to_the_range():
    z = to_depth(np.array([-1.0, 0.0, 0.01, 1.0, 100.0, np.nan]), (0.2, 20.0))
    np.testing.assert_allclose(z, [20.0, 20.0, 20.0, 1.0, 0.2, 20.0], rtol=1e-6)
    pred = np.random.default_rng(0).uniform(0, 5, (2, 8, 8))
    z = minmax_depth(pred, (0.5, 10.0))
    assert z.shape == pred.shape and z.min() >= 0.5 - 1e-6 and z.max() <= 10.0 + 1e-5
    near = np.unravel_index(pred[0].argmax(), (8, 8))
    assert z[0][near] == pytest.approx(0.5)  # the highest prediction is the nearest


def test_a_calibration_round_trips_and_makes_depth(tmp_path):
    cal = Calibration(0.5, 0.1, "light", "ab" * 32, {"seeds": [2100]})
    cal.write(tmp_path / "c.json")
    back = Calibration.read(tmp_path / "c.json", "synthesizer 'midas-warp'")
    assert back == cal
    np.testing.assert_allclose(back.depth(np.array([1.8, 0.0]), (0.2, 20.0)), [1.0, 10.0], rtol=1e-6)


def test_the_training_loss_is_invariant_to_positive_scale_and_shift_only():
    g = torch.Generator().manual_seed(0)
    target = torch.rand(2, 32, 32, generator=g) + 0.1
    pred = target + 0.05 * torch.randn(2, 32, 32, generator=g)
    mask = torch.ones_like(target, dtype=torch.bool)
    base = ssi_loss(pred, target, mask)
    assert ssi_loss(target, target, mask) == pytest.approx(0.0, abs=1e-6)
    assert ssi_loss(3.0 * pred + 7.0, target, mask) == pytest.approx(float(base), rel=1e-4)
    assert ssi_loss(-pred, target, mask) > 10 * base  # depth in place of inverse depth is wrong, not equivalent
