"""From MiDaS's relative inverse depth to metric depth: ``1 / z = s * pred + t``, fitted once, offline.

MiDaS predicts inverse depth up to an unknown scale and shift (affine-invariant
disparity). Two numbers per network, fitted robustly over every pixel of calibration
views whose true depth is known (procedural homes the benchmark never evaluates),
turn it into metric depth for any later image: the maintainers' recipe (MiDaS issues
#42, #171), with one global ``(s, t)`` instead of one per image, since a synthesizer
sees no depth.

The fit (:func:`fit_inverse_depth`): a least-median-of-squares search over lines
through random pairs of points (robust to up to half the points being outliers), then
iteratively reweighted least squares, Huber weights and then Tukey's biweight, the
residual scale re-estimated from the median absolute deviation at each step. A calibration is stored
as JSON beside the weights, with what it was fitted on and the SHA-256 of the weights
it belongs to (:class:`Calibration`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ssga_core import CheckpointError, InputError, MissingWeightsError

HUBER_K = 1.345
"""Huber's constant (95% efficiency under Gaussian noise), in units of the robust residual scale."""
TUKEY_C = 4.685
"""Tukey's biweight constant (95% efficiency), in units of the robust residual scale."""
MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class Fit:
    """A robust line fit ``y = scale * x + shift`` and how well it holds."""

    scale: float
    shift: float
    sigma: float
    """Robust scale of the residuals (1.4826 x their median absolute deviation)."""
    inliers: float
    """Share of points within 3 sigma of the line."""
    points: int


def fit_inverse_depth(pred: np.ndarray, inverse_depth: np.ndarray, *, seed: int = 0, trials: int = 200, iterations: int = 40) -> Fit:
    """Robust ``inverse_depth ~ scale * pred + shift`` over paired samples (any shape, flattened).

    Non-finite pairs are dropped. Raises :class:`InputError` when fewer than 2 points
    remain or ``pred`` does not vary.
    """
    x = np.asarray(pred, dtype=np.float64).ravel()
    y = np.asarray(inverse_depth, dtype=np.float64).ravel()
    if x.shape != y.shape:
        raise InputError(f"calibration: {x.size} predictions for {y.size} inverse depths")
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if x.size < 2 or np.ptp(x) <= 0:
        raise InputError(f"calibration: needs at least 2 points with varying predictions, got {x.size}")
    rng = np.random.default_rng(seed)
    # 1. Least median of squares over lines through random pairs (judged on a subsample).
    probe = rng.choice(x.size, min(x.size, 20000), replace=False)
    px, py = x[probe], y[probe]
    best, best_med = (1.0, 0.0), np.inf
    for _ in range(trials):
        i, j = rng.choice(x.size, 2, replace=False)
        if x[i] == x[j]:
            continue
        s = (y[i] - y[j]) / (x[i] - x[j])
        t = y[i] - s * x[i]
        med = np.median(np.abs(s * px + t - py))
        if med < best_med:
            best, best_med = (s, t), med
    s, t = best
    # 2. IRLS, the residual scale from the MAD of the current residuals: Huber weights
    #    first (convex: they converge from any start), then Tukey's biweight, whose
    #    weight falls to zero, so gross outliers stop pulling (Huber's still do, by k sigma each).
    for it in range(iterations):
        r = s * x + t - y
        sigma = max(MAD_TO_SIGMA * np.median(np.abs(r - np.median(r))), 1e-12)
        if it < iterations // 2:
            a = np.abs(r) / (HUBER_K * sigma)
            w = np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))
        else:
            w = np.clip(1.0 - (r / (TUKEY_C * sigma)) ** 2, 0.0, None) ** 2
        sw, swx, swy = w.sum(), (w * x).sum(), (w * y).sum()
        swxx, swxy = (w * x * x).sum(), (w * x * y).sum()
        det = sw * swxx - swx * swx
        if det <= 0:
            break
        s_new = (sw * swxy - swx * swy) / det
        t_new = (swy - s_new * swx) / sw
        done = abs(s_new - s) <= 1e-9 * max(abs(s), 1e-12) and abs(t_new - t) <= 1e-9 * max(abs(t), 1e-12)
        s, t = s_new, t_new
        if done and it >= iterations // 2:
            break
    r = s * x + t - y
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r))))
    return Fit(float(s), float(t), sigma, float((np.abs(r) <= 3 * sigma).mean()), int(x.size))


def align_per_image(pred: np.ndarray, depth: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """Least-squares ``(s, t)`` of ``1 / depth ~ s * pred + t`` on one image's ``mask``: MiDaS's evaluation alignment (needs the truth)."""
    x, y = pred[mask].astype(np.float64), 1.0 / depth[mask].astype(np.float64)
    a = np.stack([x, np.ones_like(x)], axis=1)
    (s, t), *_ = np.linalg.lstsq(a, y, rcond=None)
    return float(s), float(t)


def to_depth(inverse: np.ndarray, depth_range: tuple[float, float]) -> np.ndarray:
    """Metric depth from inverse depth, clamped to ``depth_range`` (an inverse depth <= 1 / far gives far)."""
    near, far = depth_range
    inverse = np.where(np.isfinite(inverse), inverse, 1.0 / far)
    return (1.0 / np.clip(inverse, 1.0 / far, 1.0 / near)).astype(np.float32)


def minmax_depth(pred: np.ndarray, depth_range: tuple[float, float]) -> np.ndarray:
    """The min/max prior (MiDaS #268): each image's prediction spread over ``depth_range`` in inverse depth.

    ``1 / z = A p + 1 / far`` with ``p`` the prediction scaled to [0, 1] between its
    1st and 99th percentiles and ``A = 1 / near - 1 / far``. Needs no calibration and
    knows no scale: for random weights (tests) and uncalibrated files.
    """
    near, far = depth_range
    pred = np.asarray(pred, dtype=np.float64)
    batch = pred if pred.ndim == 3 else pred[None]
    lo, hi = np.percentile(batch.reshape(len(batch), -1), [1, 99], axis=1)
    p = np.clip((batch - lo[:, None, None]) / np.maximum(hi - lo, 1e-12)[:, None, None], 0.0, 1.0)
    depth = to_depth((1.0 / near - 1.0 / far) * p + 1.0 / far, depth_range)
    return depth if pred.ndim == 3 else depth[0]


@dataclass(frozen=True)
class Calibration:
    """A fitted ``1 / z = scale * pred + shift`` for one weights file, and where it came from."""

    scale: float
    shift: float
    network: str
    weights_sha256: str
    provenance: dict[str, Any] = field(default_factory=dict)

    def depth(self, pred: np.ndarray, depth_range: tuple[float, float]) -> np.ndarray:
        """Metric depth of a prediction, clamped to ``depth_range``."""
        return to_depth(self.scale * np.asarray(pred, dtype=np.float64) + self.shift, depth_range)

    def write(self, path: Path) -> None:
        from ssga_bench import write_json

        write_json(path, asdict(self))

    @classmethod
    def read(cls, path: Path, who: str) -> Calibration:
        """The calibration in ``path``; a missing or malformed file is one :class:`CheckpointError` line."""
        if not path.is_file():
            raise MissingWeightsError(
                f"{who}: config field 'calibration': {path}: no such file; make it with "
                f"'python -m ssga_synthesizer_midas_warp.calibrate --weights <file>', or set calibration = 'minmax'"
            )
        try:
            data = json.loads(path.read_text())
            return cls(float(data["scale"]), float(data["shift"]), str(data["network"]), str(data["weights_sha256"]), dict(data.get("provenance", {})))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise CheckpointError(
                f"{who}: config field 'calibration': {path} is not a calibration ({type(exc).__name__}: {exc}); expected JSON with scale, shift, network, weights_sha256"
            ) from None

    def check(self, network: str, weights_sha256: str, path: Path, who: str) -> Calibration:
        if self.network != network or self.weights_sha256 != weights_sha256:
            raise CheckpointError(
                f"{who}: config field 'calibration': {path} was fitted for the {self.network!r} network with weights "
                f"{self.weights_sha256[:12]}, not for these ({network!r}, {weights_sha256[:12]}); calibrate these weights"
            )
        return self


def calibration_path(weights: Path) -> Path:
    """Where the calibration of a weights file lives: beside it, ``<stem>.calibration.json``."""
    return weights.with_name(f"{weights.stem}.calibration.json")


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()
